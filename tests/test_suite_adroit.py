"""The Adroit suite: exact initial-state restore, the unified 30-D action, the success rule, experts, datasets, CLI."""

import json
import os

import gymnasium as gym
import numpy as np
import pytest
from conftest import requires_rendering, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.suites import make_suite, suite_config_from_dict
from adademo_lerobot.suites.adroit import (
    OBS_DIM,
    SUCCESS_STEPS,
    TASK_BLOCKS,
    TASKS,
    UNIFIED_ACTUATORS,
    AdroitSuiteConfig,
    make_raw_env,
    native_obs_indices,
    state_dict_of,
)
from adademo_lerobot.suites.gym_robotics import env_max_episode_steps, register_envs

DOOR, HAMMER, PEN, RELOCATE = TASKS


@pytest.fixture(scope="module")
def suite():
    return make_suite(AdroitSuiteConfig(tasks="door,hammer,pen,relocate"))


def _actions(n=50, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 30)).astype(np.float32)


def test_initial_state_is_the_stock_env_state_and_restores_like_the_stock_env(suite):
    """The state is `get_env_state()` in `_state_space` order; the stock env restores it without this package,
    and a restore steps exactly like the stock env reset with the same seed."""
    register_envs()
    for task in TASKS:
        state = suite.sample_initial_state(task, 11)
        stock = gym.make(task)
        stock_obs, _ = stock.reset(seed=11)
        full = stock.unwrapped.get_env_state()
        keys = list(stock.unwrapped._state_space.spaces)
        np.testing.assert_array_equal(state, np.concatenate([np.ravel(full[k]) for k in keys]))
        env = suite.make_env(task, terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": state})
        idx = native_obs_indices(task)
        for action in _actions(50, seed=2):
            np.testing.assert_array_equal(obs["environment_state"][idx], stock_obs)
            stock_obs, _, _, _, stock_info = stock.step(action[env.native_index])
            obs, _, _, _, info = env.step(action)
            assert info["goal_achieved"] == bool(stock_info["success"])
        # Anyone can restore the vector with the stock env alone (another env, another history).
        other = gym.make(task)
        other.reset(seed=5)
        restored, _ = other.reset(options={"initial_state_dict": state_dict_of(other.unwrapped, state)})
        obs, _ = env.reset(options={"initial_state": state})
        np.testing.assert_allclose(obs["environment_state"][idx], restored, rtol=0, atol=1e-12)


def test_initial_state_sizes(suite):
    """(Seeding and exact restore are in test_suite_contract.py.) The state is the env's full `get_env_state()`."""
    sizes = {DOOR: 63, HAMMER: 69, PEN: 64, RELOCATE: 78}
    for task in TASKS:
        assert suite.sample_initial_state(task, 123).shape == (sizes[task],)


def test_unified_action_reaches_the_right_native_actuators_and_unused_dims_do_nothing(suite):
    expected_native = {
        DOOR: list(range(2, 30)),
        HAMMER: [3, 4] + list(range(6, 30)),
        PEN: list(range(6, 30)),
        RELOCATE: list(range(30)),
    }
    for task in TASKS:
        env = suite.make_env(task, terminate_on_success=False)
        raw = env._raw
        names = [raw.model.actuator(i).name for i in range(raw.model.nu)]
        assert [UNIFIED_ACTUATORS[k] for k in env.native_index] == names  # read from the model, by name
        assert list(env.native_index) == expected_native[task]
        env.reset(seed=3)
        action = _actions(1, seed=4)[0]
        env.step(action)
        np.testing.assert_allclose(raw.data.ctrl, raw.act_mean + action[env.native_index] * raw.act_rng)
        # Dimensions the task does not have change nothing.
        unused = np.setdiff1d(np.arange(30), env.native_index)
        other = action.copy()
        other[unused] = -other[unused]
        a, b = (
            suite.make_env(task, terminate_on_success=False),
            suite.make_env(task, terminate_on_success=False),
        )
        obs_a, _ = a.reset(seed=6)
        obs_b, _ = b.reset(seed=6)
        for _t in range(20):
            obs_a, *_ = a.step(action)
            obs_b, *_ = b.step(other)
        np.testing.assert_array_equal(obs_a["environment_state"], obs_b["environment_state"])


def test_observation_layout_onehot_dimensions_and_step_limits(suite):
    assert (suite.name, suite.fps, suite.action_dim, suite.state_dim, suite.env_state_dim) == (
        "adroit",
        100,
        30,
        30,
        96,
    )
    assert AdroitSuiteConfig().max_episode_steps == 200
    for i, task in enumerate(TASKS):
        assert suite.fps == round(1.0 / make_raw_env(task).dt)
        assert env_max_episode_steps(task) == 200  # the envs' own TimeLimit, the config default
        obs, _ = suite.make_env(task).reset(seed=0)
        state = obs["environment_state"]
        assert state.shape == (OBS_DIM + 4,) and suite.task_onehot(task)[i] == 1.0
        np.testing.assert_array_equal(state[OBS_DIM:], suite.task_onehot(task))
        np.testing.assert_array_equal(obs["agent_pos"], state[:30])
        start, size = TASK_BLOCKS[task]
        others = np.setdiff1d(np.arange(30, OBS_DIM), np.arange(start, start + size))
        np.testing.assert_array_equal(state[others], 0.0)  # the other tasks' blocks are zero
        assert len(native_obs_indices(task)) == make_raw_env(task).observation_space.shape[0]


def test_success_rule_counts_goal_achieved_steps(suite):
    """Success = the env's goal achieved on at least SUCCESS_STEPS steps (DAPG: more than 25, pen: 20)."""
    assert SUCCESS_STEPS == {DOOR: 26, HAMMER: 26, PEN: 21, RELOCATE: 26}
    # A door already swung open (hinge 1.45 rad, at rest): the goal holds on every step.
    env = suite.make_env(DOOR, terminate_on_success=False)
    state = suite.sample_initial_state(DOOR, 0).copy()
    hinge = 3 + 28  # door_body_pos (3), then qpos: 28 arm/hand joints, door_hinge, latch
    state[hinge] = 1.45
    env.reset(options={"initial_state": state})
    zero = np.zeros(30)
    for t in range(1, 27):
        _, _, terminated, truncated, info = env.step(zero)
        assert info["goal_achieved"] and env.goal_achieved_steps == t
        assert info["is_success"] == (t >= 26), t
    env.step(zero)
    assert env.step(zero)[4]["is_success"]  # stays a success
    # With terminate_on_success the episode ends exactly at the 26th goal step.
    env = suite.make_env(DOOR, terminate_on_success=True)
    env.reset(options={"initial_state": state})
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(zero)
        steps += 1
        if terminated or truncated:
            break
    assert terminated and steps == 26 and info["final_info"]["is_success"]
    # A ball let go at the target: the goal holds for a few steps while it falls, fewer than 26: no success.
    env = suite.make_env(RELOCATE, terminate_on_success=False)
    state = suite.sample_initial_state(RELOCATE, 0).copy()
    obj_pos, target = state[:3], state[-3:]
    state[3 + 30 : 3 + 33] = target - obj_pos  # OBJTx/y/z: the ball's slide joints
    env.reset(options={"initial_state": state})
    flags = []
    for _ in range(200):
        _, _, terminated, truncated, info = env.step(zero)
        flags.append(info["goal_achieved"])
        assert not info["is_success"]
        if truncated:
            break
    assert 0 < sum(flags) < 26 and env.goal_achieved_steps == sum(flags)
    assert truncated and not info["final_info"]["is_success"]


def test_task_names_short_and_full_stored_canonical():
    s = make_suite(AdroitSuiteConfig(tasks="relocate,AdroitHandDoor-v1"))
    assert s.tasks == [RELOCATE, DOOR] and s.config.tasks == f"{RELOCATE},{DOOR}"
    assert make_suite(AdroitSuiteConfig(tasks="all")).tasks == TASKS
    stored = suite_config_from_dict(s.config.to_dict())
    assert stored.to_dict() == s.config.to_dict() and stored.type == "adroit"
    with pytest.raises(AdaDemoError, match="relocate"):
        make_suite(AdroitSuiteConfig(tasks="relocat"))
    with pytest.raises(AdaDemoError, match="listed twice"):
        make_suite(AdroitSuiteConfig(tasks="pen,AdroitHandPen-v1"))
    with pytest.raises(AdaDemoError, match="no scripted Adroit expert"):
        make_collector(ScriptedCollectorConfig(), make_suite(AdroitSuiteConfig(tasks="hammer")))


def test_policy_collector_runs_a_torchscript_expert():
    import torch

    from adademo_lerobot.collectors import PolicyCollectorConfig

    s = make_suite(AdroitSuiteConfig(tasks="relocate", max_episode_steps=20))
    linear = torch.nn.Linear(s.env_state_dim, 30)
    torch.nn.init.zeros_(linear.weight)
    torch.nn.init.constant_(linear.bias, 0.5)
    path = os.path.join(os.environ.get("TMPDIR", "/tmp"), f"adroit_expert_{os.getpid()}.pt")
    torch.jit.save(torch.jit.trace(linear, torch.zeros(1, s.env_state_dim)), path)
    try:
        collector = make_collector(PolicyCollectorConfig(path=path, max_attempts=1), s)
        assert collector.name == "policy"
        act = collector.expert_for(RELOCATE)
        obs, _ = s.make_env(RELOCATE).reset(seed=0)
        np.testing.assert_allclose(act(obs), 0.5, atol=1e-6)
        result = collector.collect(RELOCATE, s.sample_initial_state(RELOCATE, 0), 0)
        assert (
            result.demonstration is None and result.env_steps == 20
        )  # a constant action does not relocate the ball
    finally:
        os.remove(path)
    with pytest.raises(AdaDemoError, match="collector.path"):
        make_collector(PolicyCollectorConfig(), s)


def test_adademo_collect_cli_writes_a_stock_lerobot_dataset(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "adroit"
    run_cli(
        "adademo-collect",
        "--suite.type=adroit",
        "--suite.tasks=door",
        "--episodes_per_task=2",
        "--dataset.repo_id=local/adroit",
        f"--dataset.root={root}",
        "--seed=0",
    )
    ds = LeRobotDataset("local/adroit", root=root)
    assert ds.num_episodes == 2 and ds.fps == 100 and ds.meta.robot_type == "adroit"
    assert ds.features["observation.state"]["shape"] == (30,)
    assert ds.features["observation.environment_state"]["shape"] == (OBS_DIM + 1,)
    assert ds.features["action"]["shape"] == (30,)
    assert ds[0]["task"] == DOOR
    suite_cfg = json.loads((root / "meta" / "adademo" / "suite.json").read_text())
    assert (
        suite_cfg["type"] == "adroit" and suite_cfg["tasks"] == DOOR and suite_cfg["max_episode_steps"] == 200
    )
    meta = read_episode_metadata(root)
    assert set(meta["adademo/suite"]) == {"adroit"} and set(meta["adademo/collector"]) == {"adroit-scripted"}
    from adademo_lerobot.lerobot_plugins.env import AdaDemoEnv

    env_cfg = AdaDemoEnv(dataset_root=str(root), task="door")
    assert (
        env_cfg.task == DOOR and env_cfg.fps == 100 and env_cfg.features["environment_state"].shape == (93,)
    )


@requires_rendering
def test_pixels_state_camera_choice():
    """(Images that leave the state exact are in test_suite_contract.py.)"""
    fixed = make_suite(
        AdroitSuiteConfig(tasks="pen", obs_type="pixels_state", image_size=32, camera="vil_camera")
    )
    assert fixed.make_env(PEN).reset(seed=4)[0]["pixels"]["vil_camera"].shape == (32, 32, 3)
    with pytest.raises(AdaDemoError, match="not a camera"):
        make_suite(AdroitSuiteConfig(tasks="pen", obs_type="pixels_state", camera="nope"))
