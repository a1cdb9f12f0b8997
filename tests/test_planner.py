"""The planning expert (`--collector.type=planner`) and the within-episode snapshots it plans with: real
MetaWorld and Adroit simulation."""

import numpy as np
import pytest

from adademo_lerobot.collectors import PlannerCollectorConfig, make_collector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites import AdroitSuiteConfig, MetaWorldSuiteConfig, make_suite


def steps(env, actions):
    out = []
    for a in actions:
        obs, reward, _, _, info = env.step(a)
        out.append((obs["agent_pos"].copy(), obs["environment_state"].copy(), reward, info["is_success"]))
    return out


def assert_same(a, b):
    assert len(a) == len(b)
    for (pa, ea, ra, sa), (pb, eb, rb, sb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa, pb)
        np.testing.assert_array_equal(ea, eb)
        assert (ra, sa) == (rb, sb)


@pytest.mark.parametrize(
    "config",
    [MetaWorldSuiteConfig(tasks="pick-place-v3"), AdroitSuiteConfig(tasks="pen")],
    ids=["mw", "adroit"],
)
def test_rewind_continues_an_episode_exactly_as_a_full_restore_does(config):
    suite = make_suite(config)
    task = suite.tasks[0]
    env = suite.make_env(task, terminate_on_success=False)
    rng = np.random.default_rng(0)
    env.reset(options={"initial_state": suite.sample_initial_state(task, 3)})
    steps(env, rng.uniform(-1, 1, (7, suite.action_dim)))
    snapshot, state = env.snapshot(), env.get_state()
    ahead = rng.uniform(-1, 1, (9, suite.action_dim))
    first = steps(env, ahead)
    steps(env, rng.uniform(-1, 1, (5, suite.action_dim)))  # wander off, then come back
    env.rewind(snapshot)
    assert env.steps == 7
    assert_same(steps(env, ahead), first)
    other = suite.make_env(task, terminate_on_success=False)  # a fresh env, from the whole state
    other.reset(options={"state": state})
    assert_same(steps(other, ahead), first)
    assert not np.array_equal(first[0][1], first[-1][1])  # the actions did move something


def test_planner_demonstrates_from_a_start_and_takes_over_mid_episode_deterministically():
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    task = suite.tasks[0]
    collector = make_collector(PlannerCollectorConfig(samples=8, horizon=6, max_attempts=1), suite)
    assert collector.acts_mid_episode and collector.name == "metaworld-planner"
    initial = suite.sample_initial_state(task, 1)
    result = collector.collect(task, initial, 1)
    assert result.demonstration is not None and result.failed_attempts == 0
    # Off the start: a state 30 random steps into an episode, the planner takes over from it.
    env = suite.make_env(task, terminate_on_success=False)
    obs, _ = env.reset(options={"initial_state": initial})
    steps(env, np.random.default_rng(5).uniform(-1, 1, (30, suite.action_dim)))
    start = env.get_state()
    correction = collector.collect(task, initial, 1, start_state=start)
    demo = correction.demonstration
    assert (
        demo is not None and demo.is_correction and demo.start_step == 30 and not correction.takeover_failed
    )
    np.testing.assert_array_equal(demo.start_state, start)
    # The same state gives the same plan: the whole correction again, frame for frame.
    again = make_collector(PlannerCollectorConfig(samples=8, horizon=6, max_attempts=1), suite)
    repeat = again.collect(task, initial, 1, start_state=start).demonstration
    assert len(repeat.frames) == len(demo.frames)
    for a, b in zip(repeat.frames, demo.frames, strict=True):
        np.testing.assert_array_equal(a["action"], b["action"])
    first_action = collector.expert_first_action(task)
    np.testing.assert_array_equal(first_action(obs, start), again.expert_first_action(task)(obs, start))
    collector.close()
    again.close()


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("samples", 0, "--collector.samples must be >= 1"),
        ("horizon", -2, "--collector.horizon must be >= 1"),
        ("iterations", 0, "--collector.iterations must be >= 1"),
        ("noise", 0.0, "--collector.noise must be > 0"),
        ("temperature", -1.0, "--collector.temperature must be > 0"),
    ],
)
def test_bad_planner_fields_are_refused(field, value, match):
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    with pytest.raises(AdaDemoError, match=match):
        PlannerCollectorConfig(**{field: value}).validate(suite)
