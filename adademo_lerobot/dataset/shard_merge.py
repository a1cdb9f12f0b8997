"""A commit of Ray workers' shards (`dataset/shards.py`): the shards' episodes appended to the dataset in order, as
one transaction of the dataset's (`DemoDataset.writing`), with LeRobot's file layout and writers: one new data file
(frames re-indexed), one new episodes file, one new video file per camera (remuxed, never re-encoded), info and
stats updated, tasks when a shard brings a new one. Frames never travel through the driver: it reads each shard's
table once, and its episode row and stats came with the `Shard`.

The transaction names the files the merge creates (not the whole dataset's listing), and a `ShardMerger` keeps the
dataset's metadata from one merge to the next, so a commit costs a few milliseconds whatever the dataset's size
(`benchmarks/results/shard_merge.md`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from adademo_lerobot.core.files import COMMIT_LOCK, atomic_write_json
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import COL_COLLECTOR, COL_ROUND, COL_SOURCE, episode_provenance
from adademo_lerobot.dataset.shards import Shard, read_frames, the_one


def _reindexed(stats: dict, column: str, by: int | None = None, value: int | None = None) -> None:
    """A bookkeeping column's episode stats after the column was re-indexed: shifted `by`, or all `value` (a
    count or a spread does not change)."""
    for stat, values in stats[column].items():
        if stat not in ("count", "std"):
            stats[column][stat] = np.asarray([value if value is not None else x + by for x in values])


def _stats_columns(stats: dict) -> dict:
    """An episode's stats as LeRobot's `meta/episodes` row holds them (`stats/<feature>/<stat>` columns)."""
    return {
        f"stats/{feature}/{stat}": np.asarray(values).tolist()
        for feature, by_stat in stats.items()
        for stat, values in by_stat.items()
    }


@dataclass
class _Cursor:
    """What a merge needs of the dataset's metadata. A `ShardMerger` keeps it from one merge to the next while
    nothing else writes the dataset (`meta/info.json`'s bytes tell), so that a commit reads only its shards:
    re-reading it was a large share of a commit's ~35 ms before, which the per-task commits of a round pay many
    times (`benchmarks/results/shard_merge.md`)."""

    info: dict
    tasks: pd.DataFrame
    schema: pa.Schema  # of the `meta/episodes` rows
    last: dict  # per file kind (`data`, `meta/episodes`, `videos/<key>`): the last episode's (chunk, file)
    stats: dict  # meta/stats.json as LeRobot loads it
    stamp: bytes  # meta/info.json as read or written

    @classmethod
    def read(cls, root: Path) -> _Cursor:
        from lerobot.datasets.io_utils import load_stats

        stamp = _stamp(root)
        last_file = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))[-1]
        episodes = pq.ParquetFile(last_file)
        schema = episodes.schema_arrow
        kinds = [c.removesuffix("/chunk_index") for c in schema.names if c.endswith("/chunk_index")]
        columns = [f"{kind}/{index}" for kind in kinds for index in ("chunk_index", "file_index")]
        row = episodes.read_row_group(episodes.num_row_groups - 1, columns=columns).to_pylist()[-1]
        last = {kind: (int(row[f"{kind}/chunk_index"]), int(row[f"{kind}/file_index"])) for kind in kinds}
        tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
        return cls(read_info(root), tasks, schema, last, load_stats(root), stamp)

    def next_file(self, kind: str) -> tuple[int, int]:
        return _next_file(*self.last[kind], int(self.info["chunks_size"]))


def _stamp(root: Path) -> bytes:
    """What tells that something else wrote the dataset: every write rewrites info.json (its totals change), and a
    file's bytes, unlike its mtime, cannot stay the same across a rewrite that changes them."""
    return (Path(root) / "meta" / "info.json").read_bytes()


class ShardMerger:
    """Merges finished shards into one `DemoDataset` (it exists, `can_merge`): each `merge` appends the shards'
    episodes in order, as one transaction, with one new data file, one new episodes file and one new video file
    per camera (LeRobot's file layout and writers; frames re-indexed, videos remuxed, never re-encoded). Reads
    each shard's frames once (its episode row and stats came with the `Shard`)."""

    def __init__(self, dataset):
        self.dataset = dataset
        self._cursor: _Cursor | None = None

    def merge(self, shards: list[Shard], round_index: int, source: str, collector: str) -> list[int]:
        """Returns the shards' episode indices."""
        if not shards:
            return []
        root = self.dataset.root
        with COMMIT_LOCK:  # no other write of this process between reading the metadata and the commit
            cursor = self._cursor
            if cursor is None or cursor.stamp != _stamp(root):  # first merge, or another write came between
                cursor = _Cursor.read(root)
            self._cursor = None  # until this merge has committed
            merge = _Merge(root, cursor, shards, round_index, source, collector)  # reads; writes nothing yet
            what = f"{len(shards)} episode{'s' * (len(shards) != 1)}"
            with self.dataset.writing(what, creates=merge.creates, rewrites=merge.rewrites):
                merge.write()
            self._cursor = merge.cursor_after()
        return merge.episodes


def merge_into(dataset, shards: list[Shard], round_index: int, source: str, collector: str) -> list[int]:
    """One merge of finished shards into a `DemoDataset` (see `ShardMerger`, which keeps the metadata between
    merges); returns their episode indices."""
    return ShardMerger(dataset).merge(shards, round_index, source, collector)


class _Merge:
    """One merge: everything is read and laid out when it is built (a missing shard fails here, before the
    dataset's write transaction begins); `write` creates the new files and rewrites info and stats (and tasks
    when a shard brings a new one)."""

    def __init__(self, root: Path, cursor: _Cursor, shards: list[Shard], round_index, source, collector):
        from lerobot.datasets.utils import DEFAULT_DATA_PATH, DEFAULT_EPISODES_PATH, DEFAULT_VIDEO_PATH
        from lerobot.datasets.video_utils import get_video_duration_in_s

        self.root, self.cursor = root, cursor
        info = cursor.info
        first, frames = int(info["total_episodes"]), int(info["total_frames"])
        self.video_keys = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
        # The new file of each kind this merge writes: (chunk, file).
        kinds = ["data", "meta/episodes", *(f"videos/{key}" for key in self.video_keys)]
        self.at = {kind: cursor.next_file(kind) for kind in kinds}
        tasks, offsets = cursor.tasks, dict.fromkeys(self.video_keys, 0.0)
        self.videos: dict[str, list[Path]] = {key: [] for key in self.video_keys}  # each camera's shard files
        self.data_tables, self.rows, self.stats = [], [], []
        for k, shard in enumerate(shards):
            folder = Path(shard.path)
            data = read_frames(shard)
            row, shard_stats = dict(shard.row), {c: dict(v) for c, v in shard.stats.items()}
            task = row["tasks"][0]
            if task not in tasks.index:
                tasks = pd.concat([tasks, pd.DataFrame({"task_index": [len(tasks)]}, index=pd.Index([task]))])
            task_index, n, episode = int(tasks.loc[task, "task_index"]), data.num_rows, first + k
            for name, values in (
                ("episode_index", [episode] * n),
                ("index", range(frames, frames + n)),
                ("task_index", [task_index] * n),
            ):
                data = data.set_column(data.column_names.index(name), name, pa.array(values, pa.int64()))
            _reindexed(shard_stats, "episode_index", value=episode)
            _reindexed(shard_stats, "index", by=frames)
            _reindexed(shard_stats, "task_index", value=task_index)
            row |= {
                "episode_index": episode,
                "dataset_from_index": frames,
                "dataset_to_index": frames + n,
                **{f"{kind}/chunk_index": at[0] for kind, at in self.at.items()},
                **{f"{kind}/file_index": at[1] for kind, at in self.at.items()},
                COL_ROUND: round_index,
                **dict(
                    zip(
                        (COL_SOURCE, COL_COLLECTOR),
                        episode_provenance(source, collector, shard.is_correction, shard.by_policy),
                        strict=True,
                    )
                ),
                **_stats_columns(shard_stats),
            }
            for key in self.video_keys:
                row |= {
                    f"videos/{key}/from_timestamp": offsets[key] + row[f"videos/{key}/from_timestamp"],
                    f"videos/{key}/to_timestamp": offsets[key] + row[f"videos/{key}/to_timestamp"],
                }
                # The next episode starts where this file ends, as LeRobot's aggregation places it.
                self.videos[key].append(the_one(folder, f"videos/{key}/chunk-*/file-*.mp4"))
                offsets[key] += get_video_duration_in_s(self.videos[key][-1])
            self.data_tables.append(data)
            self.rows.append(row)
            self.stats.append(shard_stats)
            frames += n
        self.new_tasks = len(tasks) > len(cursor.tasks)
        self.tasks, self.total_frames = tasks, frames
        self.episodes = list(range(first, first + len(shards)))

        def path(template: str, kind: str, **keys) -> str:
            return template.format(chunk_index=self.at[kind][0], file_index=self.at[kind][1], **keys)

        self.data_path = path(DEFAULT_DATA_PATH, "data")
        self.meta_path = path(DEFAULT_EPISODES_PATH, "meta/episodes")
        self.video_paths = {
            key: path(DEFAULT_VIDEO_PATH, f"videos/{key}", video_key=key) for key in self.video_keys
        }
        self.creates = [self.data_path, self.meta_path, *self.video_paths.values()]
        self.rewrites = ["meta/info.json", "meta/stats.json", *["meta/tasks.parquet"] * self.new_tasks]

    def write(self) -> None:
        from lerobot.datasets.compute_stats import aggregate_stats
        from lerobot.datasets.io_utils import cast_stats_to_numpy, write_table_one_row_group_per_episode
        from lerobot.datasets.utils import serialize_dict
        from lerobot.datasets.video_utils import concatenate_video_files

        root = self.root
        for rel in self.creates:
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
        write_table_one_row_group_per_episode(pa.concat_tables(self.data_tables), root / self.data_path)
        pq.write_table(pa.Table.from_pylist(self.rows, schema=self.cursor.schema), root / self.meta_path)
        for key, rel in self.video_paths.items():
            concatenate_video_files(self.videos[key], root / rel)
        if self.new_tasks:
            self.tasks.index.name = "task"
            self.tasks.to_parquet(root / "meta" / "tasks.parquet")
        # LeRobot's write_stats but for its indentation (which needs json's pure-Python encoder, the larger part
        # of writing stats.json; any JSON reads the same); kept as LeRobot would load it back, so the next merge
        # aggregates exactly the same.
        stats = serialize_dict(aggregate_stats([self.cursor.stats, *self.stats]))
        (root / "meta" / "stats.json").write_text(json.dumps(stats))
        self.stats_written = cast_stats_to_numpy(stats)
        total = self.episodes[-1] + 1
        self.info = self.cursor.info | {
            "total_episodes": total,
            "total_frames": self.total_frames,
            "total_tasks": len(self.tasks),
            "splits": {"train": f"0:{total}"},
        }
        atomic_write_json(root / "meta" / "info.json", self.info)

    def cursor_after(self) -> _Cursor:
        last = self.cursor.last | self.at
        return _Cursor(self.info, self.tasks, self.cursor.schema, last, self.stats_written, _stamp(self.root))


def _next_file(chunk: int, file: int, chunk_size: int) -> tuple[int, int]:
    from lerobot.datasets.utils import update_chunk_file_indices

    return update_chunk_file_indices(chunk, file, chunk_size)
