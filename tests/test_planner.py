"""The planning expert (`--collector.type=planner`) and the within-episode snapshots it plans with: real
MetaWorld and Adroit simulation."""

import numpy as np
import pytest

from adademo_lerobot.collectors import PlannerCollectorConfig, make_collector
from adademo_lerobot.collectors.planner import PlannerTaskSettings, noise_generator, smooth_noise
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
        ("knot_steps", 0, "--collector.knot_steps must be >= 1"),
        ("threads", 0, "--collector.threads must be >= 1"),
        ("reward", "dense", "--collector.reward must be planning or env"),
        ("plan_decay", -0.1, r"--collector.plan_decay must be in \[0, 1\)"),
        ("plan_decay", 1.0, r"--collector.plan_decay must be in \[0, 1\)"),
    ],
)
def test_bad_planner_fields_are_refused(field, value, match):
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    with pytest.raises(AdaDemoError, match=match):
        PlannerCollectorConfig(**{field: value}).validate(suite)


def test_common_noise_draws_by_step_for_every_state_and_otherwise_by_state():
    a, b = np.zeros(5), np.arange(5.0)

    def draws(state, step, common):
        return noise_generator(state, step, common).normal(size=4)

    np.testing.assert_array_equal(draws(a, 3, True), draws(b, 3, True))  # every episode alike at one step
    assert not np.allclose(draws(a, 3, True), draws(a, 4, True))
    np.testing.assert_array_equal(draws(b, 3, False), draws(b, 9, False))  # one state, one action
    assert not np.allclose(draws(a, 3, False), draws(b, 3, False))


def test_common_noise_and_plan_decay_still_demonstrate_and_change_the_demonstration():
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    task = suite.tasks[0]
    initial = suite.sample_initial_state(task, 1)

    def actions(**fields):
        collector = make_collector(
            PlannerCollectorConfig(samples=8, horizon=6, max_attempts=1, **fields), suite
        )
        demo = collector.collect(task, initial, 1).demonstration
        collector.close()
        assert demo is not None  # reach-v3 is reached either way
        return np.stack([f["action"] for f in demo.frames])

    common = actions(common_noise=True, plan_decay=0.1)
    np.testing.assert_array_equal(common, actions(common_noise=True, plan_decay=0.1))  # reproducible
    default = actions()
    assert common.shape != default.shape or not np.allclose(common, default)


def test_task_settings_plan_the_named_task_with_its_own_fields_and_the_others_as_before():
    """reach-v3 given its own noise draws, plan decay and horizon plans as a collector with those fields for every
    task does; push-v3, not named, as the collector's own fields do (the first planned action from a start)."""
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    own = {"reach-v3": PlannerTaskSettings(common_noise=True, plan_decay=0.1, horizon=4)}

    def first_action(task: str, **fields) -> np.ndarray:
        collector = make_collector(PlannerCollectorConfig(**{"samples": 8, "horizon": 6, **fields}), suite)
        env = suite.make_env(task)
        observation, _ = env.reset(options={"initial_state": suite.sample_initial_state(task, 1)})
        action = collector.expert_first_action(task)(observation, env.unwrapped.get_state())
        env.close()
        collector.close()
        return action

    reach = first_action("reach-v3", task_settings=own)
    np.testing.assert_array_equal(
        reach, first_action("reach-v3", common_noise=True, plan_decay=0.1, horizon=4)
    )
    assert not np.allclose(reach, first_action("reach-v3"))
    np.testing.assert_array_equal(first_action("push-v3", task_settings=own), first_action("push-v3"))


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        (
            {"drawer-open-v3": PlannerTaskSettings(noise=0.2)},
            "task_settings: drawer-open-v3 not among this run's tasks",
        ),
        (
            {"reach-v3": PlannerTaskSettings(plan_decay=1.5)},
            r"task_settings of reach-v3: --collector.plan_decay",
        ),
        (
            {"reach-v3": PlannerTaskSettings(samples=0)},
            "task_settings of reach-v3: --collector.samples must be",
        ),
    ],
)
def test_bad_task_settings_are_refused(settings, match):
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    with pytest.raises(AdaDemoError, match=match):
        PlannerCollectorConfig(task_settings=settings).validate(suite)


@pytest.fixture(scope="module")
def adroit():
    return make_suite(AdroitSuiteConfig(tasks="all"))


def test_adroit_rollouts_in_c_score_exactly_the_envs_own_rewards(adroit):
    rng = np.random.default_rng(0)
    for task in adroit.tasks:
        env = adroit.make_env(task, terminate_on_success=False)
        env.reset(options={"initial_state": adroit.sample_initial_state(task, 4)})
        steps(env, rng.uniform(-1, 1, (5, adroit.action_dim)))  # mid-episode, with contacts under way
        # Outside the action box too: clipped as the env clips them.
        sequences = rng.uniform(-1.2, 1.2, (3, 12, adroit.action_dim))
        in_c = env.batched_rollouts(shaped=False).rewards(sequences)
        planning = env.batched_rollouts(shaped=True, threads=2).rewards(sequences)
        start = env.snapshot()
        for k, actions in enumerate(sequences):
            env.rewind(start)
            stepped = [reward for _, _, reward, _ in steps(env, actions)]
            np.testing.assert_allclose(in_c[k], stepped, rtol=0, atol=1e-12, err_msg=task)
        # The planning reward pays for nearing the object (the v1 envs pay for leaving it): not the env's.
        assert not np.allclose(planning, in_c), task
        env.close()


def test_smooth_noise_passes_through_its_knots_and_is_linear_between():
    noise = smooth_noise(np.random.default_rng(1), 2000, 9, 3, 4, 0.3)
    assert noise.shape == (2000, 9, 3)
    np.testing.assert_allclose(noise[:, 2], (noise[:, 0] + noise[:, 4]) / 2)
    np.testing.assert_allclose(noise[:, 7], 0.25 * noise[:, 4] + 0.75 * noise[:, 8])
    assert abs(noise[:, [0, 4, 8]].std() - 0.3) < 0.01  # knots have the asked std
    white = smooth_noise(np.random.default_rng(1), 2000, 9, 3, 1, 0.3)
    assert abs(np.corrcoef(white[:, 0, 0], white[:, 1, 0])[0, 1]) < 0.1  # knot_steps=1: independent steps


# Hammer in the slow set: the default suite stays under 15 minutes (pen, the harder one, runs by default).
@pytest.mark.parametrize("task", [pytest.param("hammer", marks=pytest.mark.slow), "pen"])
def test_planner_is_the_adroit_expert_that_had_none(adroit, task):
    """Hammer had no expert and pen's scripted one succeeded on 25 % of starts: the planner demonstrates both
    (rollouts in C), and plans the same with one thread or two."""
    suite = make_suite(AdroitSuiteConfig(tasks=task))
    name = suite.tasks[0]
    collector = make_collector(PlannerCollectorConfig(max_attempts=1), suite)
    result = collector.collect(name, suite.sample_initial_state(name, 0), 1)
    demo = result.demonstration
    assert demo is not None and result.failed_attempts == 0
    assert len(demo.frames) < 120  # well inside the 200-step limit
    env = suite.make_env(name, terminate_on_success=False)
    unused = np.setdiff1d(np.arange(suite.action_dim), env.used_action_dims)
    assert all(not frame["action"][unused].any() for frame in demo.frames)  # ignored dims stay zero
    env.reset(options={"initial_state": suite.sample_initial_state(name, 1)})
    steps(env, np.random.default_rng(2).uniform(-1, 1, (3, suite.action_dim)))
    state = env.get_state()
    threaded = make_collector(PlannerCollectorConfig(max_attempts=1, threads=2), suite)
    np.testing.assert_array_equal(
        collector.expert_first_action(name)(None, state), threaded.expert_first_action(name)(None, state)
    )
    collector.close()
    threaded.close()
    env.close()


def test_scripted_tasks_keep_their_scripted_expert_beside_the_planner():
    from adademo_lerobot.collectors import ScriptedCollectorConfig

    suite = make_suite(AdroitSuiteConfig(tasks="door,hammer"))
    config = PlannerCollectorConfig(max_attempts=1, scripted_tasks="door")
    mixed = make_collector(config, suite)
    assert mixed.name == config.expert_name(suite) == "adroit-planner+scripted:door"
    door = suite.tasks[0]
    initial = suite.sample_initial_state(door, 0)
    demo = mixed.collect(door, initial, 0).demonstration
    scripted = make_collector(
        ScriptedCollectorConfig(max_attempts=1), make_suite(AdroitSuiteConfig(tasks="door"))
    )
    alone = scripted.collect(door, initial, 0).demonstration
    assert demo is not None and len(demo.frames) == len(alone.frames)
    for a, b in zip(demo.frames, alone.frames, strict=True):
        np.testing.assert_array_equal(a["action"], b["action"])
    mixed.close()
    scripted.close()
    with pytest.raises(AdaDemoError, match="scripted_tasks: AdroitHandPen-v1 not among this run's tasks"):
        make_collector(PlannerCollectorConfig(scripted_tasks="pen"), suite)
    with pytest.raises(AdaDemoError, match="acts only from an episode's start"):
        config.check_acts_mid_episode(suite)
    with pytest.raises(
        AdaDemoError, match="scripted_tasks=hammer: no scripted Adroit expert for AdroitHandHammer"
    ):
        make_collector(PlannerCollectorConfig(scripted_tasks="hammer"), suite)


def test_scripted_first_plans_only_where_the_scripted_expert_fails():
    from adademo_lerobot.collectors import ScriptedCollectorConfig

    # drawer-close-v3 from seed 2: the scripted expert needs ~80 steps, the planner ~25: a 50-step limit
    # leaves the scripted attempt failing and the planned one succeeding.
    suite = make_suite(MetaWorldSuiteConfig(tasks="drawer-close-v3", max_episode_steps=50))
    task = suite.tasks[0]
    initial = suite.sample_initial_state(task, 2)
    small = {"samples": 8, "horizon": 6, "max_attempts": 1}
    both = make_collector(PlannerCollectorConfig(scripted_first=True, **small), suite)
    assert both.name == "metaworld-scripted+planner"
    scripted = make_collector(ScriptedCollectorConfig(max_attempts=1), suite)
    assert scripted.collect(task, initial, 2).demonstration is None
    rescued = both.collect(task, initial, 2)
    assert (
        rescued.attempts == 2 and rescued.failed_attempts == 1
    )  # the scripted attempt, then the planned one
    planned = make_collector(PlannerCollectorConfig(**small), suite).collect(task, initial, 2).demonstration
    assert rescued.demonstration is not None and len(rescued.demonstration.frames) == len(planned.frames)
    for a, b in zip(rescued.demonstration.frames, planned.frames, strict=True):
        np.testing.assert_array_equal(a["action"], b["action"])
    obs = {"environment_state": np.asarray(planned.frames[0]["observation.environment_state"], np.float64)}
    np.testing.assert_array_equal(
        both.expert_first_action(task)(obs, None), scripted.expert_first_action(task)(obs, None)
    )
    # Where the scripted expert succeeds, it alone acts.
    roomy = make_suite(MetaWorldSuiteConfig(tasks="drawer-close-v3"))
    first = make_collector(PlannerCollectorConfig(scripted_first=True, **small), roomy).collect(
        task, initial, 2
    )
    alone = (
        make_collector(ScriptedCollectorConfig(max_attempts=1), roomy).collect(task, initial, 2).demonstration
    )
    assert first.attempts == 1 and len(first.demonstration.frames) == len(alone.frames) > 50
    for a, b in zip(first.demonstration.frames, alone.frames, strict=True):
        np.testing.assert_array_equal(a["action"], b["action"])
    # A task in --collector.scripted_tasks keeps the scripted expert alone: no planned attempt after it.
    only = PlannerCollectorConfig(scripted_first=True, scripted_tasks="drawer-close-v3", **small)
    kept = make_collector(only, suite)
    assert kept.name == "metaworld-scripted+planner+scripted-only:drawer-close-v3"
    unplanned = kept.collect(task, initial, 2)
    assert unplanned.demonstration is None and unplanned.attempts == 1
    with pytest.raises(AdaDemoError, match="scripted_first=true acts only from an episode's start"):
        PlannerCollectorConfig(scripted_first=True).check_acts_mid_episode(
            make_suite(AdroitSuiteConfig(tasks="door"))
        )
