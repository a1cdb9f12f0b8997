"""Demonstrations written where they are collected (`dataset/shards.py`): a merge of one-episode shards gives the
dataset an append of the same demonstrations gives (episodes, frames, provenance, stats), stock LeRobot opens it,
and a merge that cannot finish, or is killed before its commit, changes nothing. A `ShardMerger` keeps the
dataset's metadata between merges: every test here merges more than once with one merger, and writes that it did
not make (an append, a rolled-back merge) come between."""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import file_digests, leave_free, requires_rendering

from adademo_lerobot.collectors import make_collector
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import TXN_FILE
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.shard_merge import ShardMerger, merge_into
from adademo_lerobot.dataset.shards import load_with_frames, read_frames, write_shard
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def demos_of(suite, n: int) -> list:
    collector = make_collector(ScriptedCollectorConfig(), suite)
    out = []
    for i in range(n):
        task = suite.tasks[i % len(suite.tasks)]
        out.append(collector.collect(task, suite.sample_initial_state(task, i), i).demonstration)
    return out


def frames(root: Path) -> pd.DataFrame:
    return pd.concat(pq.read_table(p).to_pandas() for p in sorted((root / "data").rglob("*.parquet")))


def appended_and_merged(tmp_path: Path, suite, n_base: int, n_new: int, batch: int) -> tuple[Path, Path]:
    demos = demos_of(suite, n_base + n_new)
    base, appended, merged = tmp_path / "base", tmp_path / "appended", tmp_path / "merged"
    DemoDataset("local/x", base, suite.config).append(suite, demos[:n_base], 0, "initial", "scripted")
    shutil.copytree(base, appended)
    shutil.copytree(base, merged)
    new = demos[n_base:]
    new[-1].is_correction, new[-1].start_step = True, 3  # provenance of a correction, as its shard says
    shards = [write_shard(tmp_path / "shards", suite, d) for d in new]
    a, merger = DemoDataset.open("local/x", appended), ShardMerger(DemoDataset.open("local/x", merged))
    for k in range(0, n_new, batch):
        a.append(suite, new[k : k + batch], 1, "budgeted", "scripted")
        assert merger.merge(shards[k : k + batch], 1, "budgeted", "scripted") == list(
            range(n_base + k, n_base + min(k + batch, n_new))
        )
    return appended, merged


def assert_same_dataset(appended: Path, merged: Path) -> None:
    """Episodes (provenance, per-episode stats), frames, info, tasks and stats equal; stock LeRobot opens both."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    check_dataset_integrity(merged)
    ea, em = read_episode_metadata(appended), read_episode_metadata(merged)
    pd.testing.assert_frame_equal(
        ea.drop(columns=["adademo/initial_state", "adademo/start_state"]),
        em.drop(columns=["adademo/initial_state", "adademo/start_state"]),
    )
    for col in ("adademo/initial_state", "adademo/start_state"):
        for x, y in zip(ea[col], em[col], strict=True):
            np.testing.assert_array_equal(x, y)
    # Every episode's own stats (LeRobot's `stats/<feature>/<stat>` columns), re-indexed ones included (up to
    # float noise: LeRobot's quantile estimate of a column of zeros is 4e-16, not 0). A merge shifts the `index`
    # column's quantiles with the column; LeRobot estimates them from a 5,000-bin histogram of the shifted
    # values: the two agree to within one bin.
    ra, rm = (
        pd.concat(pq.read_table(f).to_pandas() for f in sorted((r / "meta" / "episodes").rglob("*.parquet")))
        for r in (appended, merged)
    )
    stat_columns = [c for c in ra.columns if c.startswith("stats/")]
    assert stat_columns and set(stat_columns) == {c for c in rm.columns if c.startswith("stats/")}
    bin_width = (np.stack(ra["stats/index/max"]) - np.stack(ra["stats/index/min"])) / 5000
    for col in stat_columns:
        a, m = np.stack(ra[col].to_numpy()), np.stack(rm[col].to_numpy())
        tolerance = bin_width + 1e-9 if col.startswith("stats/index/q") else 1e-9
        assert a.shape == m.shape and np.all(np.abs(a - m) <= tolerance), col
    fa, fm = frames(appended), frames(merged)
    for col in fa.columns:
        np.testing.assert_array_equal(np.stack(fa[col].to_numpy()), np.stack(fm[col].to_numpy()), err_msg=col)
    info_a, info_m = (json.loads((r / "meta" / "info.json").read_text()) for r in (appended, merged))
    for key in ("total_episodes", "total_frames", "total_tasks", "splits", "features"):
        assert info_a[key] == info_m[key], key
    pd.testing.assert_frame_equal(
        pd.read_parquet(appended / "meta" / "tasks.parquet"),
        pd.read_parquet(merged / "meta" / "tasks.parquet"),
    )
    stats_a, stats_m = (json.loads((r / "meta" / "stats.json").read_text()) for r in (appended, merged))
    assert stats_a.keys() == stats_m.keys()
    for feature, by_stat in stats_a.items():
        for stat, value in by_stat.items():
            # The index's quantiles are the shifted estimates above.
            rtol = 1e-4 if feature == "index" and stat.startswith("q") else 1e-6
            np.testing.assert_allclose(stats_m[feature][stat], value, rtol=rtol, err_msg=f"{feature} {stat}")
    stock = LeRobotDataset("local/x", root=merged, video_backend="pyav")
    assert stock.num_episodes == info_a["total_episodes"] and stock.num_frames == len(fa)
    np.testing.assert_array_equal(stock[len(stock) - 1]["action"].numpy(), fa["action"].iloc[-1])


def test_merged_shards_are_the_appended_demonstrations(tmp_path):
    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3,drawer-close-v3").build()
    # The base has two of the three tasks: a shard brings the third (a new task row). Three merges of one merger.
    appended, merged = appended_and_merged(tmp_path, suite, n_base=2, n_new=7, batch=3)
    assert_same_dataset(appended, merged)
    em = read_episode_metadata(merged)
    assert em["adademo/source"].iloc[-1] == "correction" and em["adademo/start_step"].iloc[-1] == 3


def test_a_merger_sees_the_writes_it_did_not_make(tmp_path, small_disk):
    """Between two merges of one merger: an append through LeRobot's writer, then a merge that a full disk stops
    (rolled back: byte for byte as before). The merges after them still give what appends give."""
    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3").build()
    demos = demos_of(suite, 8)
    appended, merged = tmp_path / "appended", small_disk / "merged"
    for root in (appended, merged):
        DemoDataset("local/x", root, suite.config).append(suite, demos[:1], 0, "initial", "scripted")
    a = DemoDataset.open("local/x", appended)
    for batch in (demos[1:3], demos[3:4], demos[4:6], demos[6:]):
        a.append(suite, batch, 1, "budgeted", "scripted")
    shards = [write_shard(tmp_path / "shards", suite, d) for d in demos]
    m = DemoDataset.open("local/x", merged)
    merger = ShardMerger(m)
    assert merger.merge(shards[1:3], 1, "budgeted", "scripted") == [1, 2]
    m.append(suite, demos[3:4], 1, "budgeted", "scripted")
    before = file_digests(merged)
    filler = leave_free(small_disk, 40 * 1024)  # room for the transaction's backups, not for the new files
    with pytest.raises(AdaDemoError, match="No space left on device") as failed:
        merger.merge(shards[4:6], 1, "budgeted", "scripted")
    # Arrow's message: it failed writing the merge's own files, not the backups.
    assert "Error writing bytes to file" in str(failed.value.__cause__)
    assert file_digests(merged) == before
    filler.unlink()
    assert merger.merge(shards[4:6], 1, "budgeted", "scripted") == [4, 5]
    assert merger.merge(shards[6:], 1, "budgeted", "scripted") == [6, 7]
    assert_same_dataset(appended, merged)


def test_a_merge_killed_before_its_commit_is_rolled_back_when_the_dataset_is_opened(tmp_path):
    """A merge names its new files in the transaction (not the whole dataset's listing): a process killed after
    writing every file but before the commit leaves a dataset that the next open rolls back, byte for byte."""
    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3").build()
    demos = demos_of(suite, 5)
    root = tmp_path / "ds"
    DemoDataset("local/x", root, suite.config).append(suite, demos[:1], 0, "initial", "scripted")
    shards = [write_shard(tmp_path / "shards", suite, d) for d in demos[1:]]
    merger = ShardMerger(DemoDataset.open("local/x", root))
    merger.merge(shards[:2], 1, "budgeted", "scripted")
    before = file_digests(root)
    # The kill comes where a merge has written everything and not committed yet: after its last write (info).
    script = f"""
import os, pickle, sys
from adademo_lerobot.dataset import shard_merge as S
from adademo_lerobot.dataset.store import DemoDataset
written = S.atomic_write_json
S.atomic_write_json = lambda *args: (written(*args), os._exit(9))
S.merge_into(DemoDataset.open("local/x", {str(root)!r}), pickle.loads(sys.stdin.buffer.read()), 1, "b", "s")
"""
    proc = subprocess.run([sys.executable, "-c", script], input=pickle.dumps(shards[2:]), capture_output=True)
    assert proc.returncode == 9, proc.stderr.decode()[-2000:]
    txn = json.loads((root / TXN_FILE).read_text())
    assert set(txn) == {"creates", "backed_up"} and len(txn["creates"]) == 2
    assert all((root / rel).exists() for rel in txn["creates"])
    DemoDataset.open("local/x", root)  # rolls back
    assert file_digests(root) == before
    assert merger.merge(shards[2:], 1, "budgeted", "scripted") == [3, 4]  # the same merger merges on
    check_dataset_integrity(root)


@requires_rendering
def test_merged_shards_with_a_camera_decode_to_the_appended_frames(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    suite = MetaWorldSuiteConfig(tasks="reach-v3", obs_type="pixels_state", image_size=32).build()
    appended, merged = appended_and_merged(tmp_path, suite, n_base=1, n_new=3, batch=3)
    a = LeRobotDataset("local/x", root=appended, video_backend="pyav")
    m = LeRobotDataset("local/x", root=merged, video_backend="pyav")
    assert len(a) == len(m)
    key = "observation.images.corner2"
    for i in (0, len(a) // 2, len(a) - 1):  # first, middle and last frame: every video is where its rows say
        np.testing.assert_array_equal(a[i][key].numpy(), m[i][key].numpy())


def test_a_merge_that_cannot_finish_changes_nothing(tmp_path):
    suite = MetaWorldSuiteConfig(tasks="reach-v3").build()
    demos = demos_of(suite, 3)
    root = tmp_path / "ds"
    DemoDataset("local/x", root, suite.config).append(suite, demos[:1], 0, "initial", "scripted")
    shards = [write_shard(tmp_path / "shards", suite, d) for d in demos[1:]]
    Path(shards[1].path).unlink()  # written on a node this machine cannot see
    before = file_digests(root)
    with pytest.raises(AdaDemoError, match="which this machine cannot see: .*--ray.worker_writes=false"):
        merge_into(DemoDataset.open("local/x", root), shards, 1, "budgeted", "scripted")
    assert file_digests(root) == before


def test_a_pickled_demonstration_is_the_same_sent_as_one_array_per_key():
    """As a Ray worker sends it back with --ray.worker_writes=false: Ray ships each array as its own buffer."""
    demo = demos_of(MetaWorldSuiteConfig(tasks="push-v3").build(), 1)[0]
    buffers = []
    sent = pickle.loads(pickle.dumps(demo, protocol=5, buffer_callback=buffers.append), buffers=buffers)
    assert len(buffers) <= len(demo.frames[0]) + 2  # its frames' keys, its initial and start states
    assert sent.num_frames == demo.num_frames > 10 and sent.frames[0].keys() == demo.frames[0].keys()
    for ours, theirs in zip(demo.frames, sent.frames, strict=True):
        for key, value in ours.items():
            assert theirs[key].dtype == value.dtype and np.array_equal(theirs[key], value), key
    assert (sent.task, sent.seed, sent.start_step) == (demo.task, demo.seed, demo.start_step)
    np.testing.assert_array_equal(sent.initial_state, demo.initial_state)


def test_a_state_shard_is_what_lerobots_writer_writes(tmp_path):
    """State shards are written without LeRobot's per-episode dataset (a quarter of the worker's time), their
    frames as an Arrow file: the table (schema and its metadata included), the episode row and the stats must be
    exactly what LeRobot's writer gives, a correction's provenance too."""
    from adademo_lerobot.dataset.shards import _write_with_lerobot

    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3").build()
    demos = demos_of(suite, 2)
    demos[1].is_correction, demos[1].start_step = True, 5
    for demo in demos:
        ours = write_shard(tmp_path / "ours", suite, demo)
        lerobots = _write_with_lerobot(tmp_path / "lerobot" / str(demo.seed), suite, demo)
        assert Path(ours.path).parent == tmp_path / "ours" and not list((tmp_path / "ours").glob(".*"))
        assert ours.row.keys() == lerobots.row.keys()
        for key, value in lerobots.row.items():
            np.testing.assert_array_equal(np.asarray(ours.row[key]), np.asarray(value), err_msg=key)
        # As the driver gets it from a Ray worker: pickled, without its row and stats, which whoever merges it
        # reads from the shard itself, exactly (dtypes included).
        sent = pickle.loads(pickle.dumps(ours))
        assert sent.row is None and sent.stats is None and sent.num_frames == ours.num_frames
        described, frames_read = load_with_frames(sent.path)
        assert frames_read.equals(read_frames(ours))
        assert described.row.keys() == ours.row.keys()
        for (
            key,
            value,
        ) in ours.row.items():  # NaN among the full states' values: equal as arrays, not as lists
            np.testing.assert_array_equal(np.asarray(described.row[key]), np.asarray(value), err_msg=key)
        assert ours.stats.keys() == lerobots.stats.keys() == described.stats.keys()
        for key, stats in lerobots.stats.items():
            assert ours.stats[key].keys() == stats.keys() == described.stats[key].keys()
            for name, value in stats.items():
                np.testing.assert_array_equal(ours.stats[key][name], value, err_msg=f"{key} {name}")
                assert described.stats[key][name].dtype == ours.stats[key][name].dtype, f"{key} {name}"
                np.testing.assert_array_equal(described.stats[key][name], value, err_msg=f"{key} {name}")
        a, b = read_frames(ours), read_frames(lerobots)
        assert b.equals(pq.read_table(next(Path(lerobots.path).rglob("data/*/*.parquet"))))
        assert a.schema.equals(b.schema, check_metadata=True) and a.equals(b)
        assert (ours.task, ours.seed, ours.num_frames, ours.start_step, ours.is_correction) == (
            lerobots.task,
            lerobots.seed,
            lerobots.num_frames,
            lerobots.start_step,
            lerobots.is_correction,
        )


def a_round_appended(tmp_path: Path, suite, demos: list) -> tuple[Path, Path]:
    """Two datasets of the first two demonstrations: one with the rest appended as round 1 (what a round's merges
    must give), one to merge them into."""
    appended, merged = tmp_path / "appended", tmp_path / "merged"
    for root in (appended, merged):
        DemoDataset("local/x", root, suite.config).append(suite, demos[:2], 0, "initial", "scripted")
    DemoDataset.open("local/x", appended).append(suite, demos[2:], 1, "budgeted", "scripted")
    return appended, merged


def test_a_stopped_round_merges_the_shards_its_journal_committed_and_goes_on_from_them(tmp_path):
    """With a journal, a commit of shards is a journal line and merges come later, in larger batches. A run
    stopped before it merged (two commits journaled, one demonstration buffered) leaves the dataset as it was;
    the next run merges the committed shards (none collected again), replaces a commit whose shard a crash lost,
    and ends with the dataset that appending every demonstration in order gives."""
    from adademo_lerobot.dataset.ledger import RoundJournal
    from adademo_lerobot.dataset.shards import shard_folder
    from adademo_lerobot.strategies.round_commits import OrderedAppender, merge_journaled_shards

    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3").build()
    demos = demos_of(suite, 10)
    appended, merged = a_round_appended(tmp_path, suite, demos)
    folder = shard_folder(merged, 1)

    def run(new_demos: list) -> tuple[OrderedAppender, int]:
        """A run of the round: first what a stopped run committed (how many), then these demonstrations."""
        dataset = DemoDataset.open("local/x", merged)
        appender = OrderedAppender(
            dataset, suite, 1, "budgeted", "scripted", 2, None, RoundJournal(merged, 1)
        )
        resumed = merge_journaled_shards(appender)
        for demo in new_demos:
            appender.add(demo.task, write_shard(folder, suite, demo))
        return appender, resumed

    def dataset_files() -> dict:
        return {rel: digest for rel, digest in file_digests(merged).items() if "journal" not in rel}

    before = dataset_files()
    assert run(demos[2:7])[1] == 0  # stopped: 2 + 2 committed, the fifth still buffered
    assert dataset_files() == before  # nothing merged yet: the dataset as it was
    journal = RoundJournal(merged, 1)
    assert [len(e["shards"]) for e in journal.of_type("shards")] == [2, 2]
    lost = journal.of_type("shards")[1]["shards"][1][0]
    assert not Path(lost).is_absolute()  # relative to the dataset's parent folder
    (merged.parent / lost).unlink()  # a machine crash lost the fourth shard its journal committed

    # The next run merges three, collects the lost one and the rest again, and is stopped before a merge.
    assert run(demos[5:9])[1] == 3
    assert read_episode_metadata(merged)["adademo/seed"].tolist()[2:] == [d.seed for d in demos[2:5]]
    third, resumed = run(
        []
    )  # merges what the second run committed: the lost one's replacement and three more
    assert resumed == 4
    assert merge_journaled_shards(third) == 0  # what is merged is not merged again
    third, resumed = run(demos[9:])
    assert resumed == 0
    third.close()
    assert_same_dataset(appended, merged)

    DemoDataset.open("local/x", merged).append(suite, demos[:1], 2, "budgeted", "scripted")
    RoundJournal(merged, 1).append(
        {"type": "shards", "at": 3, "shards": [[lost, demos[2].task, 12345]]}, sync=True
    )
    with pytest.raises(AdaDemoError, match="changed since round 1 stopped: its episode 3 is .* seed 12345"):
        merge_journaled_shards(
            OrderedAppender(
                DemoDataset.open("local/x", merged), suite, 1, "b", "s", 2, None, RoundJournal(merged, 1)
            )
        )


def test_a_stopped_round_moved_with_its_shards_merges_them_where_they_are_now(tmp_path):
    """A user who moves a stopped round's dataset (to a bigger disk after a full one, say) moves its shard folder
    beside it: the resumed round merges the shards its journal committed from there instead of collecting them
    again."""
    from adademo_lerobot.dataset.ledger import RoundJournal
    from adademo_lerobot.dataset.shards import shard_folder
    from adademo_lerobot.strategies.round_commits import OrderedAppender, merge_journaled_shards

    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3").build()
    demos = demos_of(suite, 5)
    root = tmp_path / "first-disk" / "dataset"
    DemoDataset("local/x", root, suite.config).append(suite, demos[:1], 0, "initial", "scripted")
    stopped = OrderedAppender(
        DemoDataset.open("local/x", root), suite, 1, "budgeted", "scripted", 2, None, RoundJournal(root, 1)
    )
    for demo in demos[1:5]:
        stopped.add(demo.task, write_shard(shard_folder(root, 1), suite, demo))  # two commits journaled
    assert read_info(root)["total_episodes"] == 1  # not merged yet: the run stops here

    shutil.move(tmp_path / "first-disk", tmp_path / "second-disk")
    moved = tmp_path / "second-disk" / "dataset"
    resumed = OrderedAppender(
        DemoDataset.open("local/x", moved), suite, 1, "budgeted", "scripted", 2, None, RoundJournal(moved, 1)
    )
    assert merge_journaled_shards(resumed) == 4
    resumed.close()
    assert read_episode_metadata(moved)["adademo/seed"].tolist() == [d.seed for d in demos]
    check_dataset_integrity(moved)


def test_merges_laid_out_ahead_and_written_elsewhere_commit_in_order(tmp_path, monkeypatch):
    """A round's driver lays merges out before the earlier ones are committed, and their files are written
    elsewhere meanwhile (a Ray worker; here threads, held until every merge is laid out, so that four are in
    flight at once, the first bringing a new task). Committed in order, they give what appends give."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from adademo_lerobot.dataset.ledger import RoundJournal
    from adademo_lerobot.dataset.shard_merge import prepare
    from adademo_lerobot.dataset.shards import shard_folder
    from adademo_lerobot.strategies import round_commits

    monkeypatch.setattr(round_commits, "MERGE_EVERY", 2)
    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3,drawer-close-v3").build()
    demos = demos_of(suite, 10)
    appended, merged = a_round_appended(tmp_path, suite, demos)

    gate, pool, laid_out = threading.Event(), ThreadPoolExecutor(2), []

    class Writing:  # a merge being written by another thread, as a Ray worker's result is pending
        def __init__(self, plan):
            self.future = pool.submit(lambda: (gate.wait(), prepare(plan))[1])

        def ready(self) -> bool:
            return self.future.done()

        def result(self) -> dict:
            return self.future.result()

    def prepare_merge(plan):
        laid_out.append(plan.first)
        return Writing(plan)

    journal = RoundJournal(merged, 1)
    dataset = DemoDataset.open("local/x", merged)
    appender = round_commits.OrderedAppender(
        dataset, suite, 1, "budgeted", "scripted", 1, None, journal, prepare_merge
    )
    for demo in demos[2:]:
        appender.add(demo.task, write_shard(shard_folder(merged, 1), suite, demo))
    assert laid_out == [2, 4, 6, 8] and read_episode_metadata(merged).shape[0] == 2  # none committed yet
    gate.set()
    appender.close()
    assert_same_dataset(appended, merged)
    assert not list(shard_folder(merged, 1).iterdir())  # merged shards and staged files are gone
