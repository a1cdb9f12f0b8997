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
from adademo_lerobot.dataset.layout import TXN_FILE
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.shard_merge import ShardMerger, merge_into
from adademo_lerobot.dataset.shards import read_frames, write_shard
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
    # The kill comes where a merge has written everything and not committed yet: the end of `_Merge.write`.
    script = f"""
import os, pickle, sys
from adademo_lerobot.dataset import shard_merge as S
from adademo_lerobot.dataset.store import DemoDataset
written = S._Merge.write
S._Merge.write = lambda self: (written(self), os._exit(9))
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
    shutil.rmtree(shards[1].path)  # written on a node this machine cannot see
    before = file_digests(root)
    with pytest.raises(AdaDemoError, match="which this machine cannot see: .*--ray.worker_writes=false"):
        merge_into(DemoDataset.open("local/x", root), shards, 1, "budgeted", "scripted")
    assert file_digests(root) == before


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
        # As the driver gets it from a Ray worker: pickled (its stats travel packed in one array).
        sent = pickle.loads(pickle.dumps(ours))
        assert ours.stats.keys() == lerobots.stats.keys() == sent.stats.keys()
        for key, stats in lerobots.stats.items():
            assert ours.stats[key].keys() == stats.keys() == sent.stats[key].keys()
            for name, value in stats.items():
                np.testing.assert_array_equal(ours.stats[key][name], value, err_msg=f"{key} {name}")
                assert sent.stats[key][name].dtype == ours.stats[key][name].dtype, f"{key} {name}"
                np.testing.assert_array_equal(sent.stats[key][name], value, err_msg=f"{key} {name}")
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
