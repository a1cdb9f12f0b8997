"""Where the expert takes over a failed rollout (`adademo_lerobot.collectors.takeover`): the rules on hand-made rollouts, in
milliseconds, and the whole simulator state that a correction starts from, restored at random steps."""

import numpy as np
import pytest

from adademo_lerobot.collectors.takeover import (
    TakeoverArgs,
    check_demo_start,
    first_disagreement,
    stall_step,
    takeover_step,
)
from adademo_lerobot.core.episodes import RolloutTrace
from adademo_lerobot.core.errors import AdaDemoError


def trace_of(observations: list[list[float]], actions: list[list[float]]) -> RolloutTrace:
    states = [np.array([float(t)]) for t in range(len(observations))]
    return RolloutTrace(
        states,
        [{"environment_state": np.asarray(o, np.float64)} for o in observations],
        [np.asarray(a, np.float32) for a in actions],
    )


def test_first_disagreement_needs_that_many_steps_in_a_row():
    distances = [0.0, 0.9, 0.9, 0.1, 0.9, 0.9, 0.9, 0.9]
    assert first_disagreement(distances, threshold=0.5, consecutive=3) == 4
    assert first_disagreement(distances, threshold=0.5, consecutive=1) == 1
    assert first_disagreement(distances, threshold=0.95, consecutive=1) is None
    assert first_disagreement(distances, threshold=0.5, consecutive=5) is None

    def lazy():  # the rule stops reading once it has found its step (the expert is asked no further)
        yield from [1.0, 1.0]
        raise AssertionError("read past the disagreement")

    assert first_disagreement(lazy(), threshold=0.5, consecutive=2) == 0


def test_stall_step_is_where_the_rollout_stopped_changing():
    moving_then_still = [[0.0], [1.0], [2.0], [3.0], [3.001], [3.0], [3.0]]
    assert stall_step(np.asarray(moving_then_still), tolerance=0.01) == 3
    assert stall_step(np.asarray([[0.0], [1.0], [2.0]]), tolerance=0.01) == 2  # moving to the end
    assert stall_step(np.asarray([[5.0], [5.0]]), tolerance=0.01) == 0  # never moved


def test_takeover_step_under_each_rule():
    observations = [[float(t)] for t in range(8)] + [[7.0]] * 12  # moves for 7 steps, then stalls
    policy = [[0.0, 0.0]] * 19
    expert = np.zeros((19, 2))
    expert[10:14] = [1.0, 0.0]  # disagrees from step 10 for 4 steps
    trace = trace_of(observations, policy)

    def expert_action(t):
        return expert[t]

    args = TakeoverArgs(rule="disagreement", threshold=0.5, consecutive=3, backoff=2)
    assert takeover_step(trace, args, expert_action) == (8, "disagreement")
    args.backoff = 20  # never before the start
    assert takeover_step(trace, args, expert_action) == (0, "disagreement")
    # They never disagree for 5 steps in a row: the backoff rule decides (2 steps before the stall at step 7).
    args = TakeoverArgs(rule="disagreement", threshold=0.5, consecutive=5, backoff=2)
    assert takeover_step(trace, args, expert_action) == (5, "backoff")
    assert takeover_step(trace, TakeoverArgs(rule="backoff", backoff=3)) == (4, "backoff")


@pytest.mark.parametrize(
    "demo_start, changes, match",
    [
        ("midway", {}, "unknown --demo_start='midway'"),
        ("takeover", {"rule": "random"}, "unknown --takeover.rule='random'"),
        ("takeover", {"threshold": -0.1}, "--takeover.threshold must be >= 0"),
        ("takeover", {"backoff": -2}, "--takeover.backoff must be >= 0"),
        ("takeover", {"consecutive": 0}, "--takeover.consecutive must be >= 1"),
    ],
)
def test_bad_takeover_flags(demo_start, changes, match):
    with pytest.raises(AdaDemoError, match=match.replace("[", r"\[")):
        check_demo_start(demo_start, TakeoverArgs(**changes))


def test_a_takeover_state_the_expert_fails_from_falls_back_to_the_initial_state():
    """MetaWorld's push expert cannot push with the gripper already closed: from such a state the correction
    fails after `takeover.attempts` attempts, and (fallback `initial`) the expert demonstrates from the failed
    episode's initial state instead; with fallback `none` the failure gets nothing."""
    from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
    from adademo_lerobot.suites import make_suite
    from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

    suite = make_suite(MetaWorldSuiteConfig(tasks="push-v3"))
    env = suite.make_env("push-v3", terminate_on_success=False)
    initial = suite.sample_initial_state("push-v3", 3)
    env.reset(options={"initial_state": initial})
    for _ in range(30):  # drift away with the gripper closed
        env.step(np.array([0.3, -0.2, 0.1, 0.9], np.float32))
    stuck = env.get_state()
    collector = make_collector(ScriptedCollectorConfig(max_attempts=2), suite)

    result = collector.collect("push-v3", initial, 3, stuck, TakeoverArgs(attempts=1, fallback="initial"))
    assert result.takeover_failed and result.demonstration is not None
    demo = result.demonstration
    assert not demo.is_correction and demo.start_step == 0 and result.start_step == 0
    assert result.attempts >= 2 and demo.attempts == result.attempts  # one there, then from the start
    assert result.env_steps >= 300 + len(demo.frames)  # the failed attempt ran the whole step limit

    result = collector.collect("push-v3", initial, 3, stuck, TakeoverArgs(attempts=2, fallback="none"))
    assert result.takeover_failed and result.demonstration is None and result.attempts == 2
    assert result.start_step == 30
