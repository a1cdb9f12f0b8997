"""adademo-collect, the dataset writer and the scripted expert collector, end to end on real files."""

import json
import os

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import assert_cli_error, file_digests, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.core.seeds import fresh_state_seed
from adademo_lerobot.dataset.layout import EPISODE_COLUMNS
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.loop.collect import collect_fresh
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig, make_raw_env


def test_stock_lerobot_loads_six_episodes_with_adademo_columns(reach_push_dataset):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/demo", root=reach_push_dataset)
    assert ds.num_episodes == 6
    assert {"observation.state", "observation.environment_state", "action"} <= set(ds.features)
    assert ds.features["observation.environment_state"]["shape"] == (39 + 2,)
    item = ds[0]
    assert item["task"] == "reach-v3"
    schema = pq.read_schema(next((reach_push_dataset / "meta" / "episodes").rglob("*.parquet")))
    assert set(EPISODE_COLUMNS) <= set(schema.names)
    assert str(schema.field("adademo/initial_state").type) == "list<element: double>"
    assert str(schema.field("adademo/seed").type) == "int64"
    assert str(schema.field("adademo/round").type) == "int64"
    suite_cfg = json.loads((reach_push_dataset / "meta" / "adademo" / "suite.json").read_text())
    assert suite_cfg["type"] == "metaworld" and suite_cfg["tasks"] == "reach-v3,push-v3"
    assert suite_cfg["obs_type"] == "state" and suite_cfg["image_size"] == 128


def test_metadata_round_trip(reach_push_dataset):
    meta = read_episode_metadata(reach_push_dataset)
    assert list(meta.index) == list(range(6))
    assert list(meta["task"]) == ["reach-v3"] * 3 + ["push-v3"] * 3
    assert set(meta["adademo/round"]) == {0} and set(meta["adademo/source"]) == {"initial"}
    assert set(meta["adademo/collector"]) == {"metaworld-scripted"} and set(meta["adademo/suite"]) == {
        "metaworld"
    }
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    for task in ("reach-v3", "push-v3"):
        rows = meta[meta["task"] == task]
        # The same seed gives the same initial states, stored as exact float64.
        assert list(rows["adademo/seed"]) == [fresh_state_seed(0, 0, task, k) for k in range(3)]
        for _, row in rows.iterrows():
            np.testing.assert_array_equal(
                row["adademo/initial_state"], suite.sample_initial_state(task, row["adademo/seed"])
            )


def _episode_frames(root, episode_index):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/demo", root=root, episodes=[episode_index])
    env_state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.environment_state"]])
    actions = np.stack([np.asarray(x) for x in ds.hf_dataset["action"]])
    return env_state, actions


def test_stock_metaworld_replay_reproduces_observations_and_success(reach_push_dataset):
    meta = read_episode_metadata(reach_push_dataset)
    for ep, row in meta.iterrows():
        env_state, actions = _episode_frames(reach_push_dataset, ep)
        raw = make_raw_env(row["task"])  # bare MetaWorld env, goal observable
        raw._last_rand_vec = np.array(row["adademo/initial_state"])
        raw._freeze_rand_vec = True
        obs, _ = raw.reset()
        success = False
        for t in range(len(actions)):
            np.testing.assert_allclose(obs, env_state[t, :39], atol=1e-6, rtol=0)
            obs, _, _, _, info = raw.step(actions[t])
            success |= bool(info["success"])
        assert success, f"episode {ep} does not end in success on replay"


def test_suite_api_replay_for_several_tasks(tmp_path):
    tasks = ["pick-place-v3", "door-open-v3", "drawer-open-v3"]
    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(tasks)))
    dataset = DemoDataset("local/replay", tmp_path / "ds", suite.config)
    collect_fresh(suite, dataset, dict.fromkeys(tasks, 1), seed=3, round_index=0, source="initial")
    meta = read_episode_metadata(tmp_path / "ds")
    assert len(meta) == 3
    for ep, row in meta.iterrows():
        env_state, actions = _episode_frames(tmp_path / "ds", ep)
        env = suite.make_env(row["task"], terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": row["adademo/initial_state"]})
        success = False
        for t in range(len(actions)):
            np.testing.assert_allclose(obs["environment_state"], env_state[t], atol=1e-6, rtol=0)
            obs, _, _, _, info = env.step(actions[t])
            success |= info["is_success"]
        assert success


def test_expert_retries_and_skips_failed_initial_states(tmp_path):
    """peg-insert-side-v3's scripted expert fails on some layouts: retried, then counted, never saved."""
    suite = make_suite(MetaWorldSuiteConfig(tasks="peg-insert-side-v3"))
    collector = make_collector(ScriptedCollectorConfig(max_attempts=3), suite)
    failed = retried_ok = failed_draw = None
    for draw in range(80):
        seed = fresh_state_seed(0, 0, "peg-insert-side-v3", draw)
        result = collector.collect(
            "peg-insert-side-v3", suite.sample_initial_state("peg-insert-side-v3", seed), seed
        )
        if result.demonstration is None and failed is None:
            failed, failed_draw = result, draw
        if result.demonstration is not None and result.attempts > 1 and retried_ok is None:
            retried_ok = result
        if failed and retried_ok:
            break
    assert failed is not None, "no failing layout found in 80 draws"
    assert failed.attempts == 3 and failed.failed_attempts == 3
    assert retried_ok is not None and retried_ok.demonstration.attempts == retried_ok.attempts
    # The same state with a single attempt is a plain failure.
    single = make_collector(ScriptedCollectorConfig(max_attempts=1), suite)
    assert single.collect("peg-insert-side-v3", failed.initial_state, failed.seed).attempts == 1

    # Through collect_fresh: failures are counted and their states never reach the dataset.
    dataset = DemoDataset("local/peg", tmp_path / "peg", suite.config)
    wanted = failed_draw + 1  # the draws run in order, so the failing one is among them
    summaries = collect_fresh(
        suite,
        dataset,
        {"peg-insert-side-v3": wanted},
        seed=0,
        round_index=0,
        source="initial",
        collector_config=ScriptedCollectorConfig(max_attempts=3),
    )
    summary = summaries["peg-insert-side-v3"]
    meta = read_episode_metadata(tmp_path / "peg")
    assert len(meta) == summary.demos_added == wanted
    failed_seeds = {f["seed"] for f in summary.expert_failed_states}
    assert len(failed_seeds) == summary.expert_failures >= 1
    assert failed.seed in failed_seeds
    assert not failed_seeds & set(meta["adademo/seed"])


@pytest.mark.slow
def test_resume_completes_to_the_same_dataset(tmp_path):
    args = ["--suite.tasks=reach-v3,button-press-topdown-v3", "--dataset.repo_id=local/r", "--seed=4"]
    root = tmp_path / "resumed"
    run_cli("adademo-collect", *args, "--episodes_per_task=2", f"--dataset.root={root}")
    before = file_digests(root)
    run_cli("adademo-collect", *args, "--episodes_per_task=3", f"--dataset.root={root}", "--resume=true")
    after = file_digests(root)
    # Old data and episode files are untouched: the append wrote new files.
    for rel, digest in before.items():
        if rel.startswith(("data/", "meta/episodes/")):
            assert after[rel] == digest, f"{rel} was rewritten"
    resumed = read_episode_metadata(root)
    assert len(resumed) == 6
    straight = tmp_path / "straight"
    run_cli("adademo-collect", *args, "--episodes_per_task=3", f"--dataset.root={straight}")
    direct = read_episode_metadata(straight)
    key = lambda df: sorted(zip(df["task"], df["adademo/seed"], strict=True))  # noqa: E731
    assert key(resumed) == key(direct)


def test_bad_input_gets_one_clear_error_and_no_change(tmp_path, reach_push_dataset):
    base = ["--dataset.repo_id=local/demo", "--episodes_per_task=1"]

    def fails(*args, match):
        return assert_cli_error("adademo-collect", *base, *args, match=match)

    fails("--suite.tasks=reach-v3,pusj-v3", f"--dataset.root={tmp_path / 'a'}", match="push-v3")
    fails("--suite.tasks=", f"--dataset.root={tmp_path / 'b'}", match="empty task list")
    fails(
        "--suite.tasks=reach-v3",
        "--episodes_per_task=0",
        f"--dataset.root={tmp_path / 'c'}",
        match="episodes_per_task",
    )
    assert not any(tmp_path.iterdir()), "a failed command left files behind"

    before = file_digests(reach_push_dataset)
    fails("--suite.tasks=reach-v3,push-v3", f"--dataset.root={reach_push_dataset}", match="--resume=true")
    fails("--suite.tasks=reach-v3", f"--dataset.root={reach_push_dataset}", "--resume=true", match="tasks")
    fails(
        "--suite.tasks=reach-v3,push-v3",
        "--suite.obs_type=pixels_state",
        f"--dataset.root={reach_push_dataset}",
        "--resume=true",
        match="obs_type",
    )
    assert file_digests(reach_push_dataset) == before

    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    fails(
        "--suite.tasks=reach-v3", f"--dataset.root={blocker / 'ds'}", match="a-file is a file, not a folder"
    )
    if os.geteuid() != 0:  # root ignores permission bits
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        fails("--suite.tasks=reach-v3", f"--dataset.root={ro / 'ds'}", match="not a writable folder")


def test_appends_keep_indices_contiguous_across_files(tmp_path):
    """Every append is a resumed LeRobot session writing new files: frame and episode indices must continue
    exactly where the previous append stopped, across several files, for stock LeRobot."""
    import dataclasses

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    demo = collector.collect("reach-v3", suite.sample_initial_state("reach-v3", 1), 1).demonstration
    root = tmp_path / "ds"
    ds = DemoDataset("local/a", root, suite.config)
    for k in range(4):  # every append writes new data and meta files
        indices = ds.append(
            suite, [dataclasses.replace(demo, seed=10 * k + i) for i in range(2)], k, "t", "c"
        )
        assert indices == [2 * k, 2 * k + 1]
    assert len(list((root / "meta" / "episodes").rglob("*.parquet"))) == 4
    stock = LeRobotDataset("local/a", root=root)
    n = len(demo.frames)
    assert stock.meta.total_episodes == 8 and len(stock) == 8 * n
    assert [int(i) for i in stock.hf_dataset["index"]] == list(range(8 * n))
    assert [(e["dataset_from_index"], e["dataset_to_index"]) for e in stock.meta.episodes] == [
        (i * n, (i + 1) * n) for i in range(8)
    ]
    assert list(read_episode_metadata(root)["adademo/seed"]) == [0, 1, 10, 11, 20, 21, 30, 31]


def test_appends_write_the_same_data_files_as_stock_lerobot(tmp_path):
    """Our appends skip LeRobot's image embedding (nothing to embed in state datasets) and read only the last
    episode row when resuming: the data files must be exactly what stock LeRobot writes for the same frames."""
    import dataclasses

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from adademo_lerobot.dataset.features import dataset_features

    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    demo = collector.collect("reach-v3", suite.sample_initial_state("reach-v3", 2), 2).demonstration
    demos = [dataclasses.replace(demo, seed=i) for i in range(3)]
    ours = DemoDataset("local/same", tmp_path / "ours", suite.config)
    ours.append(suite, demos[:1], 0, "t", "c")
    ours.append(suite, demos[1:], 1, "t", "c")  # a resumed session
    stock = LeRobotDataset.create(
        "local/same",
        fps=suite.fps,
        features=dataset_features(suite),
        root=tmp_path / "stock",
        robot_type="metaworld",
    )
    for i, d in enumerate(demos):
        if i == 1:
            stock.finalize()
            stock = LeRobotDataset.resume("local/same", root=tmp_path / "stock")
        for frame in d.frames:
            stock.add_frame({**frame, "task": d.task})
        stock.save_episode()
    stock.finalize()
    ours_files = sorted((tmp_path / "ours" / "data").rglob("*.parquet"))
    stock_files = sorted((tmp_path / "stock" / "data").rglob("*.parquet"))
    assert [p.relative_to(tmp_path / "ours") for p in ours_files] == [
        p.relative_to(tmp_path / "stock") for p in stock_files
    ]
    for a, b in zip(ours_files, stock_files, strict=True):
        ta, tb = pq.read_table(a), pq.read_table(b)
        assert ta.equals(tb)

        def features(
            table,
        ):  # the `datasets` schema; `map` also adds a random cache fingerprint, not part of it
            return {
                k: v
                for k, v in json.loads(table.schema.metadata[b"huggingface"]).items()
                if k != "fingerprint"
            }

        assert features(ta) == features(tb)
