"""The Fetch suite: exact initial-state restore, determinism, observation layout, experts, datasets, CLI."""

import json

import gymnasium as gym
import numpy as np
import pytest
from conftest import requires_rendering, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.suites import make_suite, suite_config_from_dict
from adademo_lerobot.suites.fetch import PROPRIO_INDICES, TASKS, FetchSuiteConfig
from adademo_lerobot.suites.gym_robotics import make_raw_env

OBJECT_TASKS = ["FetchPush-v4", "FetchPickAndPlace-v4", "FetchSlide-v4"]


@pytest.fixture(scope="module")
def suite():
    return make_suite(FetchSuiteConfig(tasks="reach,push,pick_and_place,slide"))


def _actions(n=50, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 4)).astype(np.float32)


def test_restore_equals_the_stock_gymnasium_env(suite):
    """Sampling is the stock env's own `reset(seed=k)`; a restore then steps exactly like the stock env."""
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    for task in TASKS:
        stock = gym.make(task)
        stock_obs, _ = stock.reset(seed=11)
        env = suite.make_env(task, terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": suite.sample_initial_state(task, 11)})
        for action in _actions(50, seed=2):
            n = len(stock_obs["observation"])
            expected = stock_obs["observation"] if n == 25 else np.zeros(25)
            if n != 25:
                expected[PROPRIO_INDICES] = stock_obs["observation"]
            np.testing.assert_array_equal(obs["environment_state"][:25], expected)
            np.testing.assert_array_equal(obs["environment_state"][25:28], stock_obs["desired_goal"])
            stock_obs, _, _, _, stock_info = stock.step(action)
            obs, _, _, _, info = env.step(action)
            assert info["is_success"] == bool(stock_info["is_success"])


def test_initial_state_is_the_object_pose_and_the_goal(suite):
    """(Seeding and exact restore are in test_suite_contract.py.) Reach: the goal; object tasks: pose + goal."""
    for task in TASKS:
        assert suite.sample_initial_state(task, 123).shape == ((10,) if task in OBJECT_TASKS else (3,))
    state = suite.sample_initial_state("FetchPush-v4", 3)
    obs, _ = suite.make_env("FetchPush-v4").reset(options={"initial_state": state})
    np.testing.assert_allclose(np.linalg.norm(state[3:7]), 1.0)
    np.testing.assert_array_equal(obs["environment_state"][25:28], state[7:10])
    np.testing.assert_allclose(obs["environment_state"][3:6], state[:3], atol=1e-9)
    with pytest.raises(AdaDemoError, match="another task"):
        suite.make_env("FetchReach-v4").reset(options={"initial_state": state})


def test_observation_layout_onehot_and_dimensions(suite):
    assert (suite.name, suite.fps, suite.action_dim, suite.state_dim, suite.env_state_dim) == (
        "fetch",
        25,
        4,
        10,
        32,
    )
    assert suite.fps == 1.0 / make_raw_env("FetchPush-v4").dt
    for i, task in enumerate(TASKS):
        obs, _ = suite.make_env(task).reset(seed=0)
        assert obs["environment_state"].shape == (25 + 3 + 4,)
        np.testing.assert_array_equal(obs["environment_state"][28:], suite.task_onehot(task))
        assert suite.task_onehot(task)[i] == 1.0
        np.testing.assert_array_equal(obs["agent_pos"], obs["environment_state"][PROPRIO_INDICES])
        object_part = np.setdiff1d(np.arange(25), PROPRIO_INDICES)
        if task == "FetchReach-v4":  # no object: its entries are zero, the robot's sit at the same indices
            np.testing.assert_array_equal(obs["environment_state"][object_part], 0.0)
        else:
            assert obs["environment_state"][5] > 0.4  # the object's height above the floor (on the table)


def test_vector_env_pending_states_and_success_terminates(suite):
    states = [suite.sample_initial_state("FetchPush-v4", s) for s in (1, 2)]
    envs = gym.vector.SyncVectorEnv([lambda: suite.make_env("FetchPush-v4") for _ in range(2)])
    envs.set_attr("pending_initial_state", states)
    envs.reset()
    for env, state in zip(envs.envs, states, strict=True):
        np.testing.assert_array_equal(env.initial_state, state)

    from adademo_lerobot.collectors.fetch_scripted import reach_expert

    env = suite.make_env("FetchReach-v4", terminate_on_success=True)
    obs, _ = env.reset(seed=3)
    expert = reach_expert()
    for _ in range(50):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        if terminated or truncated:
            break
    assert terminated and info["is_success"] and info["final_info"]["is_success"]
    # Without success the episode ends at the step limit (default 50, the Fetch envs' own).
    env = suite.make_env("FetchPush-v4", terminate_on_success=True)
    env.reset(seed=3)
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(np.zeros(4))
        steps += 1
        if terminated or truncated:
            break
    assert truncated and steps == 50 and "final_info" in info


def test_task_names_short_and_full_stored_canonical():
    suite = make_suite(FetchSuiteConfig(tasks="push,FetchReach-v4"))
    assert suite.tasks == ["FetchPush-v4", "FetchReach-v4"]
    assert suite.config.tasks == "FetchPush-v4,FetchReach-v4"
    assert make_suite(FetchSuiteConfig(tasks="all")).tasks == TASKS
    stored = suite_config_from_dict(suite.config.to_dict())
    assert stored.to_dict() == suite.config.to_dict() and stored.type == "fetch"
    assert FetchSuiteConfig().max_episode_steps == 50
    with pytest.raises(AdaDemoError, match="pick_and_place"):
        make_suite(FetchSuiteConfig(tasks="pick_and_plce"))
    with pytest.raises(AdaDemoError, match="FetchSlide-v4"):
        make_suite(FetchSuiteConfig(tasks="FetchSlid-v4"))
    with pytest.raises(AdaDemoError, match="listed twice"):
        make_suite(FetchSuiteConfig(tasks="push,FetchPush-v4"))
    with pytest.raises(AdaDemoError, match="empty task list"):
        make_suite(FetchSuiteConfig(tasks=""))


def test_scripted_experts_solve_reach_push_pick_and_place(suite):
    collector = make_collector(ScriptedCollectorConfig(max_attempts=1), suite)
    assert collector.name == "fetch-scripted"
    for task in ["FetchReach-v4", "FetchPush-v4", "FetchPickAndPlace-v4"]:
        successes = sum(
            collector.collect(task, suite.sample_initial_state(task, s), s).demonstration is not None
            for s in range(20)
        )
        assert successes >= 18, f"{task}: {successes}/20"


@pytest.mark.slow
def test_adademo_collect_cli_writes_a_stock_lerobot_dataset(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "fetch"
    run_cli(
        "adademo-collect",
        "--suite.type=fetch",
        "--suite.tasks=reach,push",
        "--episodes_per_task=2",
        "--dataset.repo_id=local/fetch",
        f"--dataset.root={root}",
        "--seed=0",
    )
    ds = LeRobotDataset("local/fetch", root=root)
    assert ds.num_episodes == 4 and ds.fps == 25 and ds.meta.robot_type == "fetch"
    assert ds.features["observation.state"]["shape"] == (10,)
    assert ds.features["observation.environment_state"]["shape"] == (25 + 3 + 2,)
    assert ds.features["action"]["shape"] == (4,)
    assert ds[0]["task"] == "FetchReach-v4"
    suite_cfg = json.loads((root / "meta" / "adademo" / "suite.json").read_text())
    assert suite_cfg["type"] == "fetch" and suite_cfg["tasks"] == "FetchReach-v4,FetchPush-v4"
    assert suite_cfg["max_episode_steps"] == 50
    meta = read_episode_metadata(root)
    assert list(meta["task"]) == ["FetchReach-v4"] * 2 + ["FetchPush-v4"] * 2
    assert set(meta["adademo/suite"]) == {"fetch"} and set(meta["adademo/collector"]) == {"fetch-scripted"}
    # The LeRobot env type rebuilds the same suite from the dataset (stock lerobot-eval on Fetch).
    from adademo_lerobot.lerobot_plugins.env import AdaDemoEnv

    env_cfg = AdaDemoEnv(dataset_root=str(root), task="FetchPush-v4")
    assert env_cfg.fps == 25 and env_cfg.features["environment_state"].shape == (30,)


@requires_rendering
def test_pixels_state_camera_choice():
    """(Images that leave the state exact are in test_suite_contract.py.)"""
    external = make_suite(
        FetchSuiteConfig(tasks="push", obs_type="pixels_state", image_size=32, camera="external_camera_0")
    )
    assert external.make_env("FetchPush-v4").reset(seed=4)[0]["pixels"]["external_camera_0"].shape == (
        32,
        32,
        3,
    )
    with pytest.raises(AdaDemoError, match="is not a camera of FetchPush-v4"):
        make_suite(FetchSuiteConfig(tasks="push", obs_type="pixels_state", camera="nope"))
