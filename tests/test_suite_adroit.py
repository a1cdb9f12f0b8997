"""The Adroit suite: exact initial-state restore, the unified 30-D action, the success rule, experts, datasets, CLI."""

import ctypes.util
import json
import os

import gymnasium as gym
import numpy as np
import pytest

from adademo_lerobot.collect import collect_fresh
from adademo_lerobot.collectors.base import ScriptedCollectorConfig, make_collector
from adademo_lerobot.dataset.store import DemoDataset, read_episode_metadata
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.suites.adroit import (
    OBS_DIM,
    SUCCESS_STEPS,
    TASK_BLOCKS,
    TASKS,
    UNIFIED_ACTUATORS,
    AdroitSuiteConfig,
    env_max_episode_steps,
    make_raw_env,
    native_obs_indices,
    register_envs,
    state_dict_of,
)
from adademo_lerobot.suites.base import SuiteConfig, make_suite
from conftest import run_cli

DOOR, HAMMER, PEN, RELOCATE = TASKS


@pytest.fixture(scope="module")
def suite():
    return make_suite(AdroitSuiteConfig(tasks="door,hammer,pen,relocate"))


def _actions(n=50, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 30)).astype(np.float32)


def test_restore_in_a_used_env_equals_a_fresh_env_for_50_steps(suite):
    for task in TASKS:
        state = suite.sample_initial_state(task, 7)
        used = suite.make_env(task, terminate_on_success=False)
        # Wander off: another initial state and random actions (objects move, the model's layout changes).
        used.reset(seed=99)
        for action in _actions(30, seed=1):
            used.step(action)
        obs_used, _ = used.reset(options={"initial_state": state})
        fresh = suite.make_env(task, terminate_on_success=False)
        obs_fresh, _ = fresh.reset(options={"initial_state": state})
        np.testing.assert_array_equal(obs_used["environment_state"], obs_fresh["environment_state"])
        np.testing.assert_array_equal(used.initial_state, state)
        for t, action in enumerate(_actions(50)):
            obs_used, *_ = used.step(action)
            obs_fresh, *_ = fresh.step(action)
            np.testing.assert_array_equal(obs_used["environment_state"], obs_fresh["environment_state"],
                                          err_msg=f"{task} diverged at step {t}")


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


def test_same_seed_same_initial_state_and_reset_seed_matches(suite):
    sizes = {DOOR: 63, HAMMER: 69, PEN: 64, RELOCATE: 78}
    for task in TASKS:
        a = suite.sample_initial_state(task, 123)
        b = suite.sample_initial_state(task, 123)
        c = suite.sample_initial_state(task, 124)
        assert a.dtype == np.float64 and a.shape == (sizes[task],)
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
        env = suite.make_env(task)
        obs_seed, _ = env.reset(seed=5)
        np.testing.assert_array_equal(env.initial_state, suite.sample_initial_state(task, 5))
        obs_state, _ = env.reset(options={"initial_state": suite.sample_initial_state(task, 5)})
        np.testing.assert_array_equal(obs_seed["environment_state"], obs_state["environment_state"])
    with pytest.raises(AdaDemoError, match="another task"):
        suite.make_env(DOOR).reset(options={"initial_state": suite.sample_initial_state(PEN, 0)})


def test_unified_action_reaches_the_right_native_actuators_and_unused_dims_do_nothing(suite):
    expected_native = {DOOR: list(range(2, 30)), HAMMER: [3, 4] + list(range(6, 30)), PEN: list(range(6, 30)),
                       RELOCATE: list(range(30))}
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
        a, b = suite.make_env(task, terminate_on_success=False), suite.make_env(task, terminate_on_success=False)
        obs_a, _ = a.reset(seed=6)
        obs_b, _ = b.reset(seed=6)
        for t in range(20):
            obs_a, *_ = a.step(action)
            obs_b, *_ = b.step(other)
        np.testing.assert_array_equal(obs_a["environment_state"], obs_b["environment_state"])


def test_observation_layout_onehot_dimensions_and_step_limits(suite):
    assert (suite.name, suite.fps, suite.action_dim, suite.state_dim, suite.env_state_dim) == ("adroit", 100, 30, 30, 96)
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
    stored = SuiteConfig.from_dict(s.config.to_dict())
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
        assert not result.succeeded and result.env_steps == 20  # a constant action does not relocate the ball
    finally:
        os.remove(path)
    with pytest.raises(AdaDemoError, match="collector.path"):
        make_collector(PolicyCollectorConfig(), s)


def test_collected_demos_replay_exactly_from_the_dataset(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    s = make_suite(AdroitSuiteConfig(tasks="door,relocate"))
    collector = make_collector(ScriptedCollectorConfig(), s)
    assert collector.name == "adroit-scripted"
    dataset = DemoDataset("local/adroit-replay", tmp_path / "ds", s.config)
    collect_fresh(s, collector, dataset, {t: 1 for t in s.tasks}, seed=3, round_index=0, source="initial")
    meta = read_episode_metadata(tmp_path / "ds")
    assert list(meta["task"]) == [DOOR, RELOCATE] and set(meta["adademo/collector"]) == {"adroit-scripted"}
    for ep, row in meta.iterrows():
        np.testing.assert_array_equal(row["adademo/initial_state"],
                                      s.sample_initial_state(row["task"], row["adademo/seed"]))
        ds = LeRobotDataset("local/adroit-replay", root=tmp_path / "ds", episodes=[ep])
        env_state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.environment_state"]])
        state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.state"]])
        actions = np.stack([np.asarray(x) for x in ds.hf_dataset["action"]])
        assert actions.shape[1] == 30
        env = s.make_env(row["task"], terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": np.asarray(row["adademo/initial_state"])})
        success = False
        for t in range(len(actions)):
            np.testing.assert_allclose(obs["environment_state"], env_state[t], atol=1e-6, rtol=0)
            np.testing.assert_allclose(obs["agent_pos"], state[t], atol=1e-6, rtol=0)
            obs, _, _, _, info = env.step(actions[t])
            success |= info["is_success"]
        assert success, f"episode {ep} ({row['task']}) does not end in success on replay"


def test_adademo_collect_cli_writes_a_stock_lerobot_dataset(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "adroit"
    run_cli("adademo-collect", "--suite.type=adroit", "--suite.tasks=door", "--episodes_per_task=2",
            "--dataset.repo_id=local/adroit", f"--dataset.root={root}", "--seed=0")
    ds = LeRobotDataset("local/adroit", root=root)
    assert ds.num_episodes == 2 and ds.fps == 100 and ds.meta.robot_type == "adroit"
    assert ds.features["observation.state"]["shape"] == (30,)
    assert ds.features["observation.environment_state"]["shape"] == (OBS_DIM + 1,)
    assert ds.features["action"]["shape"] == (30,)
    assert ds[0]["task"] == DOOR
    suite_cfg = json.loads((root / "meta" / "adademo" / "suite.json").read_text())
    assert suite_cfg["type"] == "adroit" and suite_cfg["tasks"] == DOOR and suite_cfg["max_episode_steps"] == 200
    meta = read_episode_metadata(root)
    assert set(meta["adademo/suite"]) == {"adroit"} and set(meta["adademo/collector"]) == {"adroit-scripted"}
    from adademo_lerobot.envs import AdaDemoEnv

    env_cfg = AdaDemoEnv(dataset_root=str(root), task="door")
    assert env_cfg.task == DOOR and env_cfg.fps == 100 and env_cfg.features["environment_state"].shape == (93,)


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None and not os.environ.get("MUJOCO_GL"),
                    reason="needs libosmesa6 or a GPU (MUJOCO_GL=egl)")
def test_pixels_state_adds_a_camera_image_and_keeps_the_state_exact():
    from adademo_lerobot.dataset.features import dataset_features

    pix = make_suite(AdroitSuiteConfig(tasks="relocate", obs_type="pixels_state", image_size=32))
    assert dataset_features(pix)["observation.images.default"]["shape"] == (32, 32, 3)
    env = pix.make_env(RELOCATE)
    obs, _ = env.reset(seed=4)
    image = obs["pixels"]["default"]
    assert image.shape == (32, 32, 3) and image.dtype == np.uint8 and image.std() > 1.0
    state_env = make_suite(AdroitSuiteConfig(tasks="relocate")).make_env(RELOCATE)
    state_obs, _ = state_env.reset(seed=4)
    for action in _actions(5):
        np.testing.assert_array_equal(obs["environment_state"], state_obs["environment_state"])
        obs, *_ = env.step(action)
        state_obs, *_ = state_env.step(action)
    frame = state_env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8 and frame.std() > 1.0
    fixed = make_suite(AdroitSuiteConfig(tasks="pen", obs_type="pixels_state", image_size=32, camera="vil_camera"))
    assert fixed.make_env(PEN).reset(seed=4)[0]["pixels"]["vil_camera"].shape == (32, 32, 3)
    with pytest.raises(AdaDemoError, match="not a camera"):
        make_suite(AdroitSuiteConfig(tasks="pen", obs_type="pixels_state", camera="nope"))


def test_one_adademo_expand_round_on_adroit(tmp_path):
    """The same commands work unchanged on Adroit: collect, train a weak ACT, expand one round."""
    from conftest import TINY_ACT, run_cli

    from adademo_lerobot.dataset.store import read_episode_metadata
    from adademo_lerobot.ledger import read_ledger

    root = tmp_path / "adroit"
    common = ["--dataset.repo_id=local/adroit", f"--dataset.root={root}"]
    run_cli("adademo-collect", "--suite.type=adroit", "--suite.tasks=door,relocate", "--episodes_per_task=1", *common)
    run_cli("adademo-train", *common, *TINY_ACT, "--steps=2", f"--output_dir={tmp_path / 'train'}")
    ckpt = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    run_cli("adademo-expand", *common, f"--policy.path={ckpt}", "--strategy=adademo", "--target_successes=1",
            "--max_demos_per_task=1", "--eval.batch_size=2")
    eps = read_episode_metadata(root)
    ledger = read_ledger(root)
    assert sorted(r["task"] for r in ledger) == ["AdroitHandDoor-v1", "AdroitHandRelocate-v1"]
    for r in ledger:
        assert r["demos_added"] == int(((eps.task == r["task"]) & (eps["adademo/round"] == 1)).sum()) <= 1
        assert r["eval_episodes"] == r["successes"] + r["failures"]
