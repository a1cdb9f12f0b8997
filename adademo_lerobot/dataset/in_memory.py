"""Training batches from tensors in memory, for datasets without camera frames.

LeRobot's `LeRobotDataset.__getitem__` decodes one parquet row (and every row of its action chunk or
observation history) per sample, in Python; on state-only datasets that costs more than the training step
itself. A state dataset is small (the quickstart's is a few MB), so `InMemoryFrames` holds its columns as
tensors and serves a whole batch with a few tensor indexing operations (`__getitems__`), following LeRobot's
own rules exactly: the same keys, dtypes and values, the same delta-timestamp windows clamped to the episode,
the same `*_is_pad` masks and the same task strings (tests/test_train.py compares them sample by sample).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import torch


def _column_tensor(column: pa.ChunkedArray) -> torch.Tensor:
    array = column.combine_chunks()
    if (
        pa.types.is_list(array.type)
        or pa.types.is_fixed_size_list(array.type)
        or pa.types.is_large_list(array.type)
    ):
        values = np.asarray(array.flatten().to_numpy(zero_copy_only=False)).reshape(len(array), -1)
    else:
        values = array.to_numpy(zero_copy_only=False)
    tensor = torch.from_numpy(np.array(values, copy=True))  # a writable copy (arrow buffers are read-only)
    # LeRobot converts each value with torch.tensor(): floats become float32, integers int64.
    if tensor.is_floating_point():
        return tensor.to(torch.float32)
    if tensor.dtype != torch.bool:
        return tensor.to(torch.int64)
    return tensor


class InMemoryFrames(torch.utils.data.Dataset):
    @staticmethod
    def supports(dataset) -> bool:
        """Only datasets without camera frames (videos or images) are held in memory."""
        return not dataset.meta.camera_keys and dataset.episodes is None

    def __init__(self, dataset):
        table = dataset.hf_dataset.data  # the arrow table: no per-row conversion
        self.columns = {name: _column_tensor(table.column(name)) for name in table.column_names}
        episodes = dataset.meta.episodes
        starts = torch.as_tensor(np.asarray(episodes["dataset_from_index"]), dtype=torch.int64)
        ends = torch.as_tensor(np.asarray(episodes["dataset_to_index"]), dtype=torch.int64)
        episode_of_frame = self.columns["episode_index"]
        self.episode_start, self.episode_end = starts[episode_of_frame], ends[episode_of_frame]
        deltas = dataset.reader.delta_indices or {}  # LeRobot 0.6: the reader owns the windows
        self.delta_indices = {k: torch.as_tensor(v, dtype=torch.int64) for k, v in deltas.items()}
        self.task_names = [str(name) for name in dataset.meta.tasks.index]

    def __len__(self) -> int:
        return len(self.columns["index"])

    def __getitems__(self, indices: list[int]) -> dict:
        """A whole batch (what LeRobot's items would collate to)."""
        idx = torch.as_tensor(indices, dtype=torch.int64)
        batch = {key: column[idx] for key, column in self.columns.items()}
        absolute = self.columns["index"][idx]
        start, end = self.episode_start[idx, None], self.episode_end[idx, None]
        for key, deltas in self.delta_indices.items():
            query = absolute[:, None] + deltas[None, :]
            batch[key] = self.columns[key][torch.maximum(start, torch.minimum(end - 1, query))]
            batch[f"{key}_is_pad"] = (query < start) | (query >= end)
        batch["task"] = [self.task_names[i] for i in batch["task_index"].tolist()]
        return batch

    def __getitem__(self, index: int) -> dict:
        batch = self.__getitems__([index])
        return {key: value[0] for key, value in batch.items()}


def whole_batch(batch: dict) -> dict:
    """The DataLoader's collate function for `InMemoryFrames`: its batches are already whole."""
    return batch
