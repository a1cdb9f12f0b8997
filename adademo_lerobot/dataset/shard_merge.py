"""A merge of Ray workers' shards (`dataset/shards.py`) into the dataset: the shards' episodes appended in order, as
one transaction of the dataset's (`DemoDataset.writing`), with LeRobot's file layout and writers: one new data file
(frames re-indexed), one new episodes file, one new video file per camera (remuxed, never re-encoded), info and
stats updated, tasks when a shard brings a new one.

The driver only lays a merge out (`ShardMerger.plan`: indices and file numbers, from the shards' lengths and tasks)
and commits it (`ShardMerger.commit`: moves the merge's files in, rewrites info and stats); writing those files
(`prepare`: reading each shard once, the row group per episode, the episodes file, the stats) can run on a Ray
worker, beside the shards. The transaction names the files the merge creates (not the whole dataset's listing), and
a `ShardMerger` keeps the dataset's metadata from one merge to the next, so a commit costs a few milliseconds
whatever the dataset's size (`benchmarks/results/shard_merge.md`, `benchmarks/results/loop_speed.md`).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import COMMIT_LOCK, atomic_write_json
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import COL_COLLECTOR, COL_ROUND, COL_SOURCE, episode_provenance
from adademo_lerobot.dataset.shards import Shard, load_with_frames, read_frames, shard_folder, the_one


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


@dataclass
class MergePlan:
    """Where one merge's shards go, laid out by the driver from the dataset's metadata and the shards' lengths and
    tasks (a few microseconds a shard). It travels light (the shards' paths, not their frames or stats), so that a
    Ray worker can write the merge's files (`prepare`) and the driver only moves them in (`ShardMerger.commit`)."""

    root: str  # the dataset's
    paths: list[str]
    first: int  # the first shard's episode index
    first_frame: int  # its first frame's index
    task_indices: list[int]
    # Per file kind (`data`, `meta/episodes`, `videos/<key>`): the new file's (chunk, file).
    at: dict[str, tuple[int, int]]
    video_keys: list[str]
    schema: pa.Schema  # of the `meta/episodes` rows
    round_index: int
    source: str
    collector: str
    tasks: pd.DataFrame  # the dataset's tasks after this merge
    new_tasks: bool
    total_frames: int  # the dataset's frames after this merge
    # Each file the merge creates (relative to the dataset) -> where `prepare` writes it.
    staged: dict[str, str]

    @property
    def episodes(self) -> list[int]:
        return list(range(self.first, self.first + len(self.paths)))

    @property
    def rewrites(self) -> list[str]:
        return ["meta/info.json", "meta/stats.json", *["meta/tasks.parquet"] * self.new_tasks]


class ShardMerger:
    """Merges finished shards into one `DemoDataset` (it exists, `can_merge`), in order, each merge one
    transaction with one new data file, one new episodes file and one new video file per camera (LeRobot's file
    layout and writers; frames re-indexed, videos remuxed, never re-encoded). A merge is three steps: `plan` (the
    driver lays it out), `prepare` (anywhere the shards are: writes its files beside them), `commit` (the driver
    moves them into the dataset and rewrites info and stats, as one transaction). `merge` does all three here.
    Several merges may be planned before the first is committed (their preparing overlaps); they are committed
    in the order they were planned."""

    def __init__(self, dataset):
        self.dataset = dataset
        self._cursor: _Cursor | None = None  # the dataset's metadata as the last commit left it
        self._planned: _Cursor | None = None  # as it will be once every planned merge is committed
        self._uncommitted = 0  # merges planned, not committed yet

    def merge(self, shards: list[Shard], round_index: int, source: str, collector: str) -> list[int]:
        """Plan, prepare (in this process) and commit one merge; returns the shards' episode indices."""
        if not shards:
            return []
        plan = self.plan(shards, round_index, source, collector)
        try:
            stats = prepare(plan, shards)
        except BaseException:
            self.abandon()
            raise
        return self.commit(plan, stats)

    def plan(self, shards: list[Shard], round_index: int, source: str, collector: str) -> MergePlan:
        with COMMIT_LOCK:
            cursor = self._planned if self._uncommitted else self._read_cursor()
            plan = _lay_out(self.dataset.root, cursor, shards, round_index, source, collector)
            self._planned, self._uncommitted = _after(cursor, plan, None), self._uncommitted + 1
        return plan

    def commit(self, plan: MergePlan, stats: dict) -> list[int]:
        """Move a prepared merge's files into the dataset and rewrite its metadata, as one transaction (rolled
        back on failure: the shards stay, to be merged again); `stats` are its episodes' aggregated stats."""
        from lerobot.datasets.compute_stats import aggregate_stats
        from lerobot.datasets.io_utils import cast_stats_to_numpy
        from lerobot.datasets.utils import serialize_dict

        root = self.dataset.root
        what = f"{len(plan.paths)} episode{'s' * (len(plan.paths) != 1)}"
        with COMMIT_LOCK:  # no other write of this process between reading the metadata and the commit
            try:
                cursor = self._read_cursor()
                if int(cursor.info["total_episodes"]) != plan.first:
                    raise AdaDemoError(
                        f"the dataset {root} was written while {what} were being merged into it (it has "
                        f"{cursor.info['total_episodes']} episodes, the merge expected {plan.first}); run one "
                        "command at a time on a dataset; the same command resumes"
                    )
                self._cursor = None  # until this merge has committed
                with self.dataset.writing(what, creates=list(plan.staged), rewrites=plan.rewrites):
                    for rel, staged in plan.staged.items():
                        (root / rel).parent.mkdir(parents=True, exist_ok=True)
                        shutil.move(staged, root / rel)  # a rename on the same file system
                    if plan.new_tasks:
                        plan.tasks.index.name = "task"
                        plan.tasks.to_parquet(root / "meta" / "tasks.parquet")
                    # LeRobot's write_stats but for its indentation (which needs json's pure-Python encoder, the
                    # larger part of writing stats.json; any JSON reads the same); kept as LeRobot would load it
                    # back, so the next merge aggregates exactly the same.
                    written = serialize_dict(aggregate_stats([cursor.stats, stats]))
                    (root / "meta" / "stats.json").write_text(json.dumps(written))
                    after = _after(cursor, plan, cast_stats_to_numpy(written))
                    atomic_write_json(root / "meta" / "info.json", after.info)
            except BaseException:
                self.abandon()
                raise
            after.stamp = _stamp(root)
            self._cursor, self._uncommitted = after, self._uncommitted - 1
        return plan.episodes

    def abandon(self) -> None:
        """Every merge planned and not committed is void (one of them failed): the next is planned afresh."""
        self._planned, self._uncommitted = None, 0

    def _read_cursor(self) -> _Cursor:
        cursor = self._cursor
        if cursor is None or cursor.stamp != _stamp(self.dataset.root):  # first merge, or another write came
            cursor = _Cursor.read(self.dataset.root)
        return cursor


def merge_into(dataset, shards: list[Shard], round_index: int, source: str, collector: str) -> list[int]:
    """One merge of finished shards into a `DemoDataset` (see `ShardMerger`, which keeps the metadata between
    merges); returns their episode indices."""
    return ShardMerger(dataset).merge(shards, round_index, source, collector)


def _lay_out(root: Path, cursor: _Cursor, shards: list[Shard], round_index, source, collector) -> MergePlan:
    from lerobot.datasets.utils import DEFAULT_DATA_PATH, DEFAULT_EPISODES_PATH, DEFAULT_VIDEO_PATH

    info = cursor.info
    first, frames = int(info["total_episodes"]), int(info["total_frames"])
    video_keys = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    kinds = ["data", "meta/episodes", *(f"videos/{key}" for key in video_keys)]
    at = {kind: cursor.next_file(kind) for kind in kinds}
    tasks, task_indices = cursor.tasks, []
    index_of_task = dict(zip(tasks.index, tasks["task_index"].astype(int), strict=True))
    for shard in shards:
        if shard.task not in index_of_task:
            index_of_task[shard.task] = len(index_of_task)
            tasks = pd.concat(
                [tasks, pd.DataFrame({"task_index": [len(tasks)]}, index=pd.Index([shard.task]))]
            )
        task_indices.append(index_of_task[shard.task])

    def path(template: str, kind: str, **keys) -> str:
        return template.format(chunk_index=at[kind][0], file_index=at[kind][1], **keys)

    creates = [path(DEFAULT_DATA_PATH, "data"), path(DEFAULT_EPISODES_PATH, "meta/episodes")]
    creates += [path(DEFAULT_VIDEO_PATH, f"videos/{key}", video_key=key) for key in video_keys]
    # Staged beside the shards (as reachable as they are), as hidden files of the merge's first episode.
    folder = shard_folder(root, round_index)
    staged = {rel: str(folder / f".merge-{first:09d}-{rel.replace('/', '.')}") for rel in creates}
    return MergePlan(
        str(root),
        [s.path for s in shards],
        first,
        frames,
        task_indices,
        at,
        video_keys,
        cursor.schema,
        round_index,
        source,
        collector,
        tasks,
        len(tasks) > len(cursor.tasks),
        frames + sum(s.num_frames for s in shards),
        staged,
    )


def _after(cursor: _Cursor, plan: MergePlan, stats: dict | None) -> _Cursor:
    """The dataset's metadata once `plan` is committed (`stats`: what stats.json then holds)."""
    total = plan.first + len(plan.paths)
    info = cursor.info | {
        "total_episodes": total,
        "total_frames": plan.total_frames,
        "total_tasks": len(plan.tasks),
        "splits": {"train": f"0:{total}"},
    }
    return _Cursor(info, plan.tasks, cursor.schema, cursor.last | plan.at, stats, b"")


def prepare(plan: MergePlan, shards: list[Shard] | None = None) -> dict:
    """Write a planned merge's files where the plan stages them (on a Ray worker, or in the driver); returns its
    episodes' stats, aggregated. Reads each shard once (its row and stats from `shards` when the caller has them,
    else from the shard's own file, with its frames)."""
    from lerobot.datasets.compute_stats import aggregate_stats
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode
    from lerobot.datasets.video_utils import concatenate_video_files, get_video_duration_in_s

    described = {s.path: s for s in shards or [] if s.row is not None}
    offsets = dict.fromkeys(plan.video_keys, 0.0)
    videos: dict[str, list[Path]] = {key: [] for key in plan.video_keys}  # each camera's shard files
    tables, rows, all_stats, frames = [], [], [], plan.first_frame
    for k, (path, task_index) in enumerate(zip(plan.paths, plan.task_indices, strict=True)):
        shard = described.get(path)
        shard, data = (shard, read_frames(shard)) if shard is not None else load_with_frames(path)
        row, stats = dict(shard.row), {c: dict(v) for c, v in shard.stats.items()}
        n, episode = data.num_rows, plan.first + k
        _reindexed(stats, "episode_index", value=episode)
        _reindexed(stats, "index", by=frames)
        _reindexed(stats, "task_index", value=task_index)
        row |= {
            "episode_index": episode,
            "dataset_from_index": frames,
            "dataset_to_index": frames + n,
            **{f"{kind}/chunk_index": at[0] for kind, at in plan.at.items()},
            **{f"{kind}/file_index": at[1] for kind, at in plan.at.items()},
            COL_ROUND: plan.round_index,
            **dict(
                zip(
                    (COL_SOURCE, COL_COLLECTOR),
                    episode_provenance(plan.source, plan.collector, shard.is_correction, shard.by_policy),
                    strict=True,
                )
            ),
            **_stats_columns(stats),
        }
        for key in plan.video_keys:
            row |= {
                f"videos/{key}/from_timestamp": offsets[key] + row[f"videos/{key}/from_timestamp"],
                f"videos/{key}/to_timestamp": offsets[key] + row[f"videos/{key}/to_timestamp"],
            }
            # The next episode starts where this file ends, as LeRobot's aggregation places it.
            videos[key].append(the_one(Path(shard.path), f"videos/{key}/chunk-*/file-*.mp4"))
            offsets[key] += get_video_duration_in_s(videos[key][-1])
        tables.append(data)
        rows.append(row)
        all_stats.append(stats)
        frames += n
    # The frames' bookkeeping columns, re-indexed for the whole merge at once.
    data = pa.concat_tables(tables)
    lengths = [t.num_rows for t in tables]
    for name, values in (
        ("episode_index", np.repeat(plan.episodes, lengths)),
        ("index", np.arange(plan.first_frame, frames)),
        ("task_index", np.repeat(plan.task_indices, lengths)),
    ):
        data = data.set_column(data.column_names.index(name), name, pa.array(values.astype(np.int64)))
    staged = [Path(p) for p in plan.staged.values()]
    try:
        staged[0].parent.mkdir(parents=True, exist_ok=True)
        write_table_one_row_group_per_episode(data, staged[0])
        pq.write_table(pa.Table.from_pylist(rows, schema=plan.schema), staged[1])
        for key, target in zip(plan.video_keys, staged[2:], strict=True):
            concatenate_video_files(videos[key], target)
    except Exception as err:  # a full disk, an unwritable folder: the dataset is untouched
        from adademo_lerobot.dataset.store import write_failure

        for path in staged:
            path.unlink(missing_ok=True)
        raise write_failure(err, Path(plan.root), f"{len(plan.paths)} episodes") from err
    return aggregate_stats(all_stats)


def _next_file(chunk: int, file: int, chunk_size: int) -> tuple[int, int]:
    from lerobot.datasets.utils import update_chunk_file_indices

    return update_chunk_file_indices(chunk, file, chunk_size)
