"""Demonstrations written where they are collected (`dataset/shards.py`): a merge of one-episode shards gives the
dataset an append of the same demonstrations gives (episodes, frames, provenance, stats), stock LeRobot opens it,
and a merge that cannot finish changes nothing."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import file_digests, requires_rendering

from adademo_lerobot.collectors import make_collector
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.shards import merge_into, read_frames, write_shard
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
    a, m = DemoDataset.open("local/x", appended), DemoDataset.open("local/x", merged)
    for k in range(0, n_new, batch):
        a.append(suite, new[k : k + batch], 1, "budgeted", "scripted")
        assert merge_into(m, shards[k : k + batch], 1, "budgeted", "scripted") == list(
            range(n_base + k, n_base + min(k + batch, n_new))
        )
    return appended, merged


def test_merged_shards_are_the_appended_demonstrations(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3,drawer-close-v3").build()
    # The base has two of the three tasks: a shard brings the third (a new task row).
    appended, merged = appended_and_merged(tmp_path, suite, n_base=2, n_new=5, batch=3)
    check_dataset_integrity(merged)
    ea, em = read_episode_metadata(appended), read_episode_metadata(merged)
    pd.testing.assert_frame_equal(
        ea.drop(columns=["adademo/initial_state", "adademo/start_state"]),
        em.drop(columns=["adademo/initial_state", "adademo/start_state"]),
    )
    for col in ("adademo/initial_state", "adademo/start_state"):
        for x, y in zip(ea[col], em[col], strict=True):
            np.testing.assert_array_equal(x, y)
    assert em["adademo/source"].iloc[-1] == "correction" and em["adademo/start_step"].iloc[-1] == 3
    # Every episode's own stats (LeRobot's `stats/<feature>/<stat>` columns), re-indexed ones included (up to
    # float noise: LeRobot's quantile estimate of a column of zeros is 4e-16, not 0).
    ra, rm = (
        pd.concat(pq.read_table(f).to_pandas() for f in sorted((r / "meta" / "episodes").rglob("*.parquet")))
        for r in (appended, merged)
    )
    stat_columns = [c for c in ra.columns if c.startswith("stats/")]
    assert stat_columns and set(stat_columns) == {c for c in rm.columns if c.startswith("stats/")}
    for col in stat_columns:
        np.testing.assert_allclose(
            np.stack(ra[col].to_numpy()), np.stack(rm[col].to_numpy()), atol=1e-9, err_msg=col
        )
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
    for feature, by_stat in stats_a.items():
        for stat, value in by_stat.items():
            np.testing.assert_allclose(stats_m[feature][stat], value, rtol=1e-6, err_msg=f"{feature} {stat}")
    stock = LeRobotDataset("local/x", root=merged, video_backend="pyav")
    assert stock.num_episodes == 7 and stock.num_frames == len(fa)
    np.testing.assert_array_equal(stock[len(stock) - 1]["action"].numpy(), fa["action"].iloc[-1])


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
        assert ours.stats.keys() == lerobots.stats.keys()
        for key, stats in lerobots.stats.items():
            assert ours.stats[key].keys() == stats.keys()
            for name, value in stats.items():
                np.testing.assert_array_equal(ours.stats[key][name], value, err_msg=f"{key} {name}")
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
