"""Episodes written where they are collected: a worker writes each demonstration it collects as a shard in a folder
every node can reach, and a commit merges finished shards into the dataset (`dataset/shard_merge.py`). A shard of
state frames is one Arrow file: the episode's table, with its episode row and stats (computed as LeRobot's writer
computes them) in the file's schema metadata; a shard with a camera is a one-episode LeRobot dataset (its writer
encodes the video) with the same description beside it (`shard.json`). Either way a shard describes itself, so a
round resumed after a stop can merge the shards its journal committed without the process that fetched them
(`read_shard`).

A shard is whole or absent: it is built under a hidden sibling name and renamed into place, so a worker killed
mid-shard leaves only a hidden `.*.partial` or `.*.adademo-creating` file or folder, which nothing merges. A state
shard is a single file so that removing it once merged is one unlink, not a folder's (`remove_shards`: on the
machine of benchmarks/results/loop_speed.md a folder's removal cost the driver ~3 ms, more than its merge).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from adademo_lerobot.core.episodes import Demonstration
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.features import dataset_features

SHARD_REPO_ID = "local/adademo-shard"
SHARD_FILE = "shard.json"  # a camera shard's description, beside its dataset
SHARD_KEY = b"adademo_shard"  # a state shard's description, in its Arrow file's schema metadata


@dataclass
class Shard:
    """A finished shard: where it is and what a round's books need of its demonstration (not its frames)."""

    path: str
    task: str
    seed: int
    num_frames: int
    start_step: int
    is_correction: bool
    # Its meta/episodes row but its `stats/*` columns (the merge makes them from `stats`), and its episode's stats
    # (numpy arrays, as LeRobot's `aggregate_stats` takes them). Both stay where the shard was written: a shard
    # sent to another process (a Ray worker's result) carries None, and whoever merges it reads them from the
    # shard itself (`load_shard`); they were most of the ~0.25 ms a result cost the driver to fetch.
    row: dict | None
    stats: dict | None
    # Its frames, relative to `path` (LeRobot's data file); "" when `path` is an Arrow file of them.
    data_file: str
    by_policy: bool = False  # a kept policy rollout (--keep_successes), not an expert's demonstration

    def __getstate__(self) -> dict:
        return {**self.__dict__, "row": None, "stats": None}


def _description(shard: Shard) -> str:
    """The shard as `read_shard` rebuilds it: its stats packed in one array, rebuilt exactly (dtypes and shapes)."""
    layout = [(f, k, v.shape, v.dtype.str) for f, by_stat in shard.stats.items() for k, v in by_stat.items()]
    values = [np.asarray(v, np.float64).ravel() for by_stat in shard.stats.values() for v in by_stat.values()]
    packed = np.concatenate(values) if values else np.zeros(0)
    state = {k: v for k, v in shard.__dict__.items() if k != "path"} | {"stats": [layout, packed.tolist()]}
    return json.dumps(state, default=lambda x: x.tolist())


def _unpacked(layout: list, packed: np.ndarray) -> dict:
    stats, at = {}, 0
    for feature, stat, shape, dtype in layout:
        size = math.prod(shape)
        value = packed[at : at + size].reshape(shape)
        stats.setdefault(feature, {})[stat] = value if dtype == "<f8" else value.astype(dtype)
        at += size
    return stats


def read_shard(path: str | Path) -> Shard | None:
    """The shard at `path`, with its row and stats; None when it is not whole (absent, or cut short)."""
    path = Path(path)
    try:
        if path.is_dir():
            description = (path / SHARD_FILE).read_text()
        else:
            with pa.OSFile(str(path)) as source:
                description = pa.ipc.open_file(source).schema.metadata[SHARD_KEY]
        shard = _described(path, description)
    except (OSError, ValueError, KeyError, TypeError, pa.ArrowInvalid):
        return None
    if shard.data_file and not (path / shard.data_file).is_file():
        return None
    return shard


def _described(path: Path, description: str | bytes) -> Shard:
    state = json.loads(description)
    layout, packed = state["stats"]
    return Shard(**(state | {"path": str(path), "stats": _unpacked(layout, np.asarray(packed, np.float64))}))


def load_shard(path: str | Path) -> Shard:
    """`read_shard`, or one clear error: a folder this machine cannot see, or a shard that is not whole."""
    shard = read_shard(path)
    if shard is None:
        raise _unseen(Path(path)) if not Path(path).exists() else AdaDemoError(f"shard {path} is not whole")
    return shard


def load_with_frames(path: str | Path) -> tuple[Shard, pa.Table]:
    """`load_shard(path)` and its `read_frames`, a state shard's one file read once (its description is in the
    frames' schema metadata); the same errors."""
    path = Path(path)
    if path.is_dir():  # a camera shard: its description beside LeRobot's files
        shard = load_shard(path)
        return shard, read_frames(shard)
    try:
        table = _arrow_frames(path)
        shard = _described(path, table.schema.metadata[SHARD_KEY])
    except (ValueError, KeyError, TypeError, pa.ArrowInvalid):
        raise AdaDemoError(f"shard {path} is not whole") from None
    return shard, _without_description(table)


def shard_folder(root: Path, round_index: int) -> Path:
    """Where a round's shards go: beside the dataset (as reachable as the dataset is), never inside it."""
    return _shards_root(root) / f"round-{round_index:03d}"


def remove_shard_folders(root: Path) -> None:
    """Every round's shard folder of the dataset at `root` (once its rounds are done)."""
    shutil.rmtree(_shards_root(root), ignore_errors=True)


def _shards_root(root: Path) -> Path:
    root = Path(root)
    return root.with_name(f".{root.name}.adademo-shards")


def remove_shards(shards: list[Shard]) -> None:
    """Merged shards are deleted (their episodes are in the dataset now)."""
    for shard in shards:
        if shard.data_file:
            shutil.rmtree(shard.path, ignore_errors=True)
        else:
            Path(shard.path).unlink(missing_ok=True)


def write_shard(folder: Path, suite, demo: Demonstration) -> Shard:
    """Write `demo` as a shard under `folder` (on the worker that collected it)."""
    path = Path(folder) / f"{demo.task}-{demo.seed}-{demo.start_step}-{uuid.uuid4().hex[:12]}"
    features = dataset_features(suite)
    if any(ft["dtype"] in ("video", "image") for ft in features.values()):
        return _write_with_lerobot(path, suite, demo)
    return _write_frames(path.with_name(f"{path.name}.arrow"), suite, demo, features)


def _write_with_lerobot(path: Path, suite, demo: Demonstration) -> Shard:
    """A shard written by LeRobot's own episode writer (camera frames are encoded there)."""
    from lerobot.datasets.io_utils import cast_stats_to_numpy

    from adademo_lerobot.dataset.store import DemoDataset

    # Round, source and collector are the commit's (set when merged); the shard keeps the rest of the row.
    DemoDataset(SHARD_REPO_ID, path, suite.config).append(suite, [demo], 0, "shard", "")
    row = pq.read_table(the_one(path, "meta/episodes/chunk-*/file-*.parquet")).to_pylist()[0]
    row = {k: v for k, v in row.items() if not k.startswith("stats/")}  # the stats travel once, as `stats`
    stats = cast_stats_to_numpy(json.loads((path / "meta" / "stats.json").read_text()))
    data = the_one(path, "data/chunk-*/file-*.parquet").relative_to(path)
    shard = _shard(path, demo, row, stats, str(data))
    (path / SHARD_FILE).write_text(_description(shard))
    return shard


def _write_frames(path: Path, suite, demo: Demonstration, features: dict) -> Shard:
    """A shard of state frames: only the table the merge reads, with its episode row and stats computed as
    LeRobot's writer computes them (its stats, schema and row layout; checked equal in tests/test_shards.py),
    without building a dataset per episode, which cost the worker ~4x more (benchmarks/results/shard_merge.md).
    The table is an Arrow file: the merge reads it in a fraction of a parquet file's open and decode."""
    from lerobot.utils.constants import DEFAULT_FEATURES

    from adademo_lerobot.dataset.stats import episode_stats
    from adademo_lerobot.dataset.store import provenance_columns

    features = {**features, **DEFAULT_FEATURES}  # LeRobot's order: ours, then its own
    n = len(demo.frames)
    episode = episode_buffer(demo, features, suite.fps)
    stats = episode_stats(episode, features)
    schema = _frames_schema(features)
    table = pa.Table.from_arrays([_column(episode[f.name], f.type) for f in schema], schema=schema)
    row = {
        "episode_index": 0,
        "tasks": [demo.task],
        "length": n,
        "data/chunk_index": 0,
        "data/file_index": 0,
        "dataset_from_index": 0,
        "dataset_to_index": n,
        "meta/episodes/chunk_index": 0,
        "meta/episodes/file_index": 0,
        **provenance_columns(demo, 0, "shard", "", suite.name),
    }
    shard = _shard(path, demo, row, stats, "")
    table = table.replace_schema_metadata(
        (table.schema.metadata or {}) | {SHARD_KEY: _description(shard).encode()}
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")  # whole or absent: renamed into place once written
    with pa.OSFile(str(partial), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)
    os.replace(partial, path)
    return shard


def episode_buffer(demo: Demonstration, features: dict, fps: int) -> dict[str, np.ndarray]:
    """The episode as LeRobot's writer holds it when it computes the episode's stats (its first episode)."""
    from lerobot.utils.constants import DEFAULT_FEATURES

    n, steps = len(demo.frames), np.arange(len(demo.frames))
    episode = {
        key: np.stack([f[key] for f in demo.frames]) for key in features if key not in DEFAULT_FEATURES
    }
    return episode | {
        "timestamp": steps / fps,
        "frame_index": steps,
        "episode_index": np.zeros(n, np.int64),
        "index": steps,
        "task_index": np.zeros(n, np.int64),
    }


_SCHEMAS: dict[str, pa.Schema] = {}


def _frames_schema(features: dict) -> pa.Schema:
    """The Arrow schema of a data file of `features`, remembered: built through `datasets` it took ~0.3 ms, a
    tenth of writing a shard (2-core AMD EPYC, 2026-12-05), and a worker writes every shard with the same."""
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    key = repr(features)
    if key not in _SCHEMAS:
        _SCHEMAS[key] = _as_parquet_reads_it(get_hf_features_from_features(features).arrow_schema)
    return _SCHEMAS[key]


def _as_parquet_reads_it(schema: pa.Schema) -> pa.Schema:
    """`schema` as a table read from LeRobot's parquet files has it (lists' items named `element`)."""
    fields = [
        pa.field(f.name, pa.list_(pa.field("element", f.type.value_type), f.type.list_size))
        if pa.types.is_fixed_size_list(f.type)
        else f
        for f in schema
    ]
    return pa.schema(fields, metadata=schema.metadata)


def _column(values: np.ndarray, kind: pa.DataType) -> pa.Array:
    if pa.types.is_fixed_size_list(kind) or pa.types.is_list(kind):
        flat = pa.array(values.reshape(len(values), -1).ravel()).cast(kind.value_type)
        return pa.FixedSizeListArray.from_arrays(flat, values.shape[1]).cast(kind)
    return pa.array(values).cast(kind)


def _shard(path: Path, demo: Demonstration, row: dict, stats: dict, data_file: str) -> Shard:
    return Shard(
        str(path),
        demo.task,
        int(demo.seed),
        len(demo.frames),
        int(demo.start_step),
        demo.is_correction,
        row,
        stats,
        data_file,
        demo.by_policy,
    )


def read_frames(shard: Shard) -> pa.Table:
    """A finished shard's frames, as LeRobot's data file holds them (schema metadata included)."""
    path = Path(shard.path)
    if shard.data_file:
        # If it is not there, raises saying which: a folder this machine cannot see, or a shard that is not whole.
        data = path / shard.data_file
        return pq.ParquetFile(data if data.is_file() else the_one(path, shard.data_file)).read()
    return _without_description(_arrow_frames(path))


def _arrow_frames(path: Path) -> pa.Table:
    """A state shard's table, its description still in the schema metadata."""
    if not path.is_file():
        raise _unseen(path)
    with pa.OSFile(str(path)) as source:
        return pa.ipc.open_file(source).read_all()


def _without_description(table: pa.Table) -> pa.Table:
    return table.replace_schema_metadata({k: v for k, v in table.schema.metadata.items() if k != SHARD_KEY})


def _unseen(path: Path) -> AdaDemoError:
    return AdaDemoError(
        f"a Ray worker wrote a demonstration to {path}, which this machine cannot see: keep the dataset on "
        "storage every Ray node reaches, or pass --ray.worker_writes=false (frames then come back to this "
        "process); the same command resumes"
    )


def the_one(folder: Path, pattern: str) -> Path:
    if not folder.is_dir():
        raise _unseen(folder)
    files = sorted(folder.glob(pattern))
    if len(files) != 1:
        raise AdaDemoError(
            f"shard {folder.parent if folder.name == 'meta' else folder} is not whole ({pattern})"
        )
    return files[0]
