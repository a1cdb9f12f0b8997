"""The MetaWorld suite: exact initial-state restore, determinism, task conditioning, bad task names."""

import json

import numpy as np
import pytest

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites import make_suite, suite_config_from_dict
from adademo_lerobot.suites.metaworld import MT10, MetaWorldSuiteConfig, make_raw_env

TASKS = ["reach-v3", "push-v3", "pick-place-v3", "peg-insert-side-v3", "door-open-v3"]


@pytest.fixture(scope="module")
def suite():
    return make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS)))


def test_restore_equals_a_fresh_stock_metaworld_env(suite):
    """(Restore in a used env and seeding are in test_suite_contract.py.)"""
    for task in TASKS:
        state = suite.sample_initial_state(task, 7)
        obs_first, _ = suite.make_env(task).reset(options={"initial_state": state})
        # A fresh env driven with stock MetaWorld calls lands on the same observation.
        raw = make_raw_env(task)
        raw._last_rand_vec = state.copy()
        raw._freeze_rand_vec = True
        raw_obs, _ = raw.reset()
        np.testing.assert_array_equal(obs_first["environment_state"][:39], raw_obs)
        # The layout shows in the observation: the goal (last 3 of the 39) is visible to the policy.
        assert np.abs(raw_obs[36:39]).sum() > 0


def _stock_reset(raw, layout=None, seed=None):
    """MetaWorld's own path: a full reset() (with hand settling, reset_model twice)."""
    raw._freeze_rand_vec = layout is not None
    if layout is None:
        raw.seeded_rand_vec = True
        raw.seed(seed)
    else:
        raw._last_rand_vec = layout.copy()
    obs, _ = raw.reset()
    return obs, np.array(raw._last_rand_vec, dtype=np.float64)


def test_fast_sampling_and_restore_equal_metaworlds_own_reset_for_every_task():
    """Sampling skips hand settling, restore runs reset_model's first pass without it and reuses the remembered
    result of the second pass's settling: each must give exactly what MetaWorld's full reset gives, layout,
    observation and the trajectory after it, for all 50 tasks."""
    from adademo_lerobot.suites.metaworld import all_task_names, restore_layout, sample_layout

    rng = np.random.default_rng(0)
    for task in all_task_names():
        stock, ours = make_raw_env(task), make_raw_env(task)
        _, layout = _stock_reset(stock, seed=11)
        np.testing.assert_array_equal(sample_layout(ours, 11), layout, err_msg=task)
        restore_layout(ours, sample_layout(ours, 12))  # another layout first (its settled hand is remembered)
        for _ in range(int(rng.integers(1, 10))):  # some history in our env only
            ours.step(rng.uniform(-1, 1, 4).astype(np.float32))
        stock_obs, _ = _stock_reset(stock, layout=layout)
        np.testing.assert_array_equal(restore_layout(ours, layout), stock_obs, err_msg=task)
        for action in rng.uniform(-1, 1, (15, 4)).astype(np.float32):
            a, b = stock.step(action), ours.step(action)
            np.testing.assert_array_equal(a[0], b[0], err_msg=task)
            assert a[1] == b[1] and a[4]["success"] == b[4]["success"], task


def test_sampler_envs_of_the_4_most_recent_tasks_are_kept_and_states_do_not_depend_on_them():
    tasks = ["reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3"]
    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(tasks)))
    first = suite.sample_initial_state("reach-v3", 3)
    reach_env = suite._samplers["reach-v3"]
    for task in tasks[1:4]:
        suite.sample_initial_state(task, 3)
    np.testing.assert_array_equal(suite.sample_initial_state("reach-v3", 3), first)
    assert suite._samplers["reach-v3"] is reach_env  # reused, not rebuilt, while among the 4 most recent
    suite.sample_initial_state("drawer-open-v3", 3)
    assert list(suite._samplers) == [
        "pick-place-v3",
        "door-open-v3",
        "reach-v3",
        "drawer-open-v3",
    ]  # push closed
    np.testing.assert_array_equal(suite.sample_initial_state("reach-v3", 3), first)


def test_pending_initial_state_for_vector_envs(suite):
    import gymnasium as gym

    states = [suite.sample_initial_state("reach-v3", s) for s in (1, 2)]
    envs = gym.vector.SyncVectorEnv([lambda: suite.make_env("reach-v3") for _ in range(2)])
    envs.set_attr("pending_initial_state", states)
    envs.reset()
    for env, state in zip(envs.envs, states, strict=True):
        np.testing.assert_array_equal(env.initial_state, state)


def test_a_held_sub_env_stops_simulating_after_its_episode_until_given_a_new_state(suite):
    """Batched evaluation: the finished sub-env repeats its final observation and its simulator stays still."""
    import gymnasium as gym
    from lerobot.envs.metaworld import TASK_POLICY_MAPPING

    expert = TASK_POLICY_MAPPING["reach-v3"]()
    envs = gym.vector.SyncVectorEnv([lambda: suite.make_env("reach-v3") for _ in range(2)])
    envs.set_attr("hold_after_episode", True)
    envs.set_attr("pending_initial_state", [suite.sample_initial_state("reach-v3", s) for s in (1, 2)])
    obs, _ = envs.reset()
    done_at = None
    for t in range(120):  # env 0 follows the expert and succeeds; env 1 stands still and runs on
        actions = np.stack([expert.get_action(obs["environment_state"][0, :39]), np.zeros(4)])
        obs, _, terminated, truncated, _ = envs.step(actions)
        if done_at is None and terminated[0]:
            done_at, final, clock = t, obs["environment_state"][0].copy(), envs.envs[0]._raw.data.time
    assert done_at is not None and done_at < 100
    assert envs.envs[0]._raw.data.time == clock  # no simulation after the episode
    np.testing.assert_array_equal(obs["environment_state"][0], final)
    assert envs.envs[1]._steps == 120  # the other episode was not held
    # A new initial state ends the hold.
    state = suite.sample_initial_state("reach-v3", 3)
    envs.set_attr("pending_initial_state", [state, state])
    envs.reset()
    assert envs.envs[0]._raw.data.time < clock
    np.testing.assert_array_equal(envs.envs[0].initial_state, state)


def test_task_onehot_and_observation_layout(suite):
    for i, task in enumerate(TASKS):
        vec = suite.task_onehot(task)
        assert vec.shape == (len(TASKS),) and vec[i] == 1.0 and vec.sum() == 1.0
        obs, _ = suite.make_env(task).reset(seed=0)
        assert obs["environment_state"].shape == (39 + len(TASKS),)
        np.testing.assert_array_equal(obs["environment_state"][39:], vec)
        np.testing.assert_array_equal(obs["agent_pos"], obs["environment_state"][:4])


def test_success_is_reported_and_terminates_in_eval_mode(suite):
    from lerobot.envs.metaworld import TASK_POLICY_MAPPING

    env = suite.make_env("reach-v3", terminate_on_success=True)
    obs, _ = env.reset(seed=3)
    policy = TASK_POLICY_MAPPING["reach-v3"]()
    for _ in range(300):
        obs, _, terminated, truncated, info = env.step(policy.get_action(obs["environment_state"][:39]))
        if terminated or truncated:
            break
    assert terminated and info["is_success"] and info["final_info"]["is_success"]


def test_mt10_group_and_any_v3_task():
    suite = make_suite(MetaWorldSuiteConfig(tasks="mt10"))
    assert suite.tasks == MT10
    suite = make_suite(MetaWorldSuiteConfig(tasks="assembly-v3,hammer-v3"))
    assert suite.tasks == ["assembly-v3", "hammer-v3"]
    stored = suite_config_from_dict(suite.config.to_dict())
    assert stored.to_dict() == suite.config.to_dict()


def test_unknown_task_names_the_closest_valid_ones():
    with pytest.raises(AdaDemoError, match="pick-place-v3"):
        make_suite(MetaWorldSuiteConfig(tasks="pick-plce-v3"))
    with pytest.raises(AdaDemoError, match="empty task list"):
        make_suite(MetaWorldSuiteConfig(tasks=" , "))
    with pytest.raises(AdaDemoError, match="obs_type"):
        make_suite(MetaWorldSuiteConfig(tasks="reach-v3", obs_type="rgb"))


def test_a_dataset_collected_with_a_task_group_accepts_the_same_group_on_the_command_line():
    from adademo_lerobot.dataset.metadata import check_same_suite
    from adademo_lerobot.suites.fetch import FetchSuiteConfig

    stored = suite_config_from_dict(make_suite(MetaWorldSuiteConfig(tasks="mt10")).config.to_dict())
    assert stored.tasks == ",".join(MT10)  # what a dataset's suite.json keeps
    check_same_suite(stored, MetaWorldSuiteConfig(tasks="mt10"))  # `--suite.tasks=mt10` again: the same suite
    check_same_suite(stored, MetaWorldSuiteConfig(tasks=",".join(MT10)))
    with pytest.raises(AdaDemoError, match="another suite configuration"):
        check_same_suite(stored, MetaWorldSuiteConfig(tasks="mt10,assembly-v3"))
    fetch = suite_config_from_dict(make_suite(FetchSuiteConfig(tasks="push")).config.to_dict())
    check_same_suite(fetch, FetchSuiteConfig(tasks="push"))  # short names too


def test_the_default_view_is_stored_as_before_robot_views_existed():
    """Datasets' suite.json and runs' settings written before `--suite.view` keep matching: the default view is not
    stored (a run started earlier resumes), a robot view is and comes back."""
    from adademo_lerobot.suites import suite_config_from_dict

    default = MetaWorldSuiteConfig(tasks="reach-v3")
    assert "view" not in default.to_dict() and "view" not in json.loads(default.to_json())
    assert suite_config_from_dict(default.to_dict()).view == "env"
    robot = MetaWorldSuiteConfig(tasks="reach-v3", view="robot")
    assert suite_config_from_dict(json.loads(robot.to_json())).view == "robot"
