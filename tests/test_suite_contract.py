"""What every suite must do the same way: exact restore in a used env and seeded initial states (all three
suites), demos that replay exactly from the dataset, camera images that leave the state untouched, and one
`adademo-expand` round through the CLI (Fetch and Adroit here; MetaWorld's are in test_collect, test_pixels and
test_expand)."""

from dataclasses import dataclass

import numpy as np
import pytest
from conftest import TINY_ACT, requires_rendering, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.loop.collect import collect_fresh
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.adroit import AdroitSuiteConfig
from adademo_lerobot.suites.fetch import FetchSuiteConfig
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


@dataclass
class Case:
    config: type
    all_tasks: str  # every task, for the restore and seed checks
    expert_tasks: str  # tasks with a scripted expert, for replay
    pixel_task: str
    expand_tasks: str
    expand_demos: int  # per task, initial and at most per round
    collector: str


CASES = {
    "fetch": Case(FetchSuiteConfig, "all", "all", "push", "reach,push", 2, "fetch-scripted"),
    "adroit": Case(
        AdroitSuiteConfig,
        "door,hammer,pen,relocate",
        "door,relocate",
        "relocate",
        "door,relocate",
        1,
        "adroit-scripted",
    ),
}
ALL_SUITES = {
    **CASES,
    "metaworld": Case(
        MetaWorldSuiteConfig,
        "reach-v3,push-v3,pick-place-v3,peg-insert-side-v3,door-open-v3",
        "",
        "",
        "",
        0,
        "metaworld-scripted",
    ),
}


def _actions(suite, n=50, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, suite.action_dim)).astype(np.float32)


@pytest.mark.parametrize("name", ALL_SUITES)
def test_restore_in_a_used_env_equals_a_fresh_env_for_50_steps(name):
    suite = make_suite(ALL_SUITES[name].config(tasks=ALL_SUITES[name].all_tasks))
    for task in suite.tasks:
        state = suite.sample_initial_state(task, 7)
        used = suite.make_env(task, terminate_on_success=False)
        # Wander off: another initial state and random actions (objects move, some tasks edit the model).
        used.reset(seed=99)
        for action in _actions(suite, 30, seed=1):
            used.step(action)
        obs_used, _ = used.reset(options={"initial_state": state})
        fresh = suite.make_env(task, terminate_on_success=False)
        obs_fresh, _ = fresh.reset(options={"initial_state": state})
        np.testing.assert_array_equal(obs_used["environment_state"], obs_fresh["environment_state"])
        np.testing.assert_array_equal(used.initial_state, state)
        # The whole state too (what a demonstration records as its start): nothing of the env's history in it.
        np.testing.assert_array_equal(used.get_state(), fresh.get_state())
        for t, action in enumerate(_actions(suite, 50)):
            obs_used, *_ = used.step(action)
            obs_fresh, *_ = fresh.step(action)
            np.testing.assert_array_equal(
                obs_used["environment_state"],
                obs_fresh["environment_state"],
                err_msg=f"{task} diverged at step {t}",
            )


@pytest.mark.parametrize("name", ALL_SUITES)
def test_whole_state_at_random_steps_of_random_episodes_restores_and_replays_exactly(name):
    """`get_state()` anywhere in an episode, restored in another (used) env, continues the episode exactly:
    observations, rewards and success, step for step. Episodes: the scripted expert with action noise where the
    suite has one (so objects get grasped and moved), random actions otherwise."""
    case = ALL_SUITES[name]
    suite = make_suite(case.config(tasks=case.all_tasks if name != "metaworld" else METAWORLD_STATE_TASKS))
    # Adroit: random actions (its scripted experts do not cover every task, nor take over mid-episode).
    collector = None if name == "adroit" else make_collector(ScriptedCollectorConfig(), suite)
    rng = np.random.default_rng(11)
    for task in suite.tasks:
        env = suite.make_env(task, terminate_on_success=False)
        obs, _ = env.reset(seed=int(rng.integers(1000)))
        expert = collector.expert_for(task) if collector else None
        steps = 80
        states, observations, actions, rewards, successes = [env.get_state()], [obs], [], [], []
        for _ in range(steps):
            noise = rng.normal(0, 0.3, suite.action_dim)
            action = (expert(obs) if expert else rng.uniform(-1, 1, suite.action_dim)) + noise
            actions.append(np.clip(action, -1, 1).astype(np.float32))
            obs, reward, _, _, info = env.step(actions[-1])
            states.append(env.get_state())
            observations.append(obs)
            rewards.append(reward)
            successes.append(info["is_success"])
        other = suite.make_env(task, terminate_on_success=False)
        other.reset(seed=123)  # used: another episode first
        for a in _actions(suite, 10):
            other.step(a)
        for t in sorted(rng.choice(steps, size=3, replace=False)):
            obs, _ = other.reset(options={"state": states[t]})
            assert other.steps == t
            np.testing.assert_array_equal(obs["environment_state"], observations[t]["environment_state"])
            np.testing.assert_array_equal(other.initial_state, env.initial_state)
            for k in range(t, steps):
                obs, reward, _, _, info = other.step(actions[k])
                np.testing.assert_array_equal(
                    obs["environment_state"],
                    observations[k + 1]["environment_state"],
                    err_msg=f"{task}: restored at step {t}, diverged at step {k}",
                )
                assert reward == rewards[k] and info["is_success"] == successes[k]
    # A state of another task is refused in one line.
    first, second = suite.tasks[0], suite.tasks[-1]
    env = suite.make_env(second)
    env.reset(seed=0)
    with pytest.raises(AdaDemoError, match="another task"):
        suite.make_env(first).reset(options={"state": env.get_state()})


# MetaWorld tasks whose episodes change Python-side state (grasp and place flags, a lazily set margin).
METAWORLD_STATE_TASKS = "reach-v3,pick-place-v3,bin-picking-v3,basketball-v3,door-open-v3,peg-insert-side-v3"


@pytest.mark.parametrize("name", ALL_SUITES)
def test_same_seed_same_initial_state_and_reset_seed_matches(name):
    suite = make_suite(ALL_SUITES[name].config(tasks=ALL_SUITES[name].all_tasks))
    for task in suite.tasks:
        a = suite.sample_initial_state(task, 123)
        b = suite.sample_initial_state(task, 123)
        c = suite.sample_initial_state(task, 124)
        assert a.dtype == np.float64
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
        env = suite.make_env(task)
        obs_seed, _ = env.reset(seed=5)
        np.testing.assert_array_equal(env.initial_state, suite.sample_initial_state(task, 5))
        obs_state, _ = env.reset(options={"initial_state": suite.sample_initial_state(task, 5)})
        np.testing.assert_array_equal(obs_seed["environment_state"], obs_state["environment_state"])
    # A state of the wrong size is refused (MetaWorld tasks with equal-size layouts cannot be told apart).
    sizes = {t: suite.sample_initial_state(t, 0).size for t in suite.tasks}
    first, second = next((a, b) for a in suite.tasks for b in suite.tasks if sizes[a] != sizes[b])
    with pytest.raises(AdaDemoError, match="another task"):
        suite.make_env(first).reset(options={"initial_state": suite.sample_initial_state(second, 0)})


@pytest.mark.parametrize("name", CASES)
def test_collected_demos_replay_exactly_from_the_dataset(name, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    suite = make_suite(CASES[name].config(tasks=CASES[name].expert_tasks))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    assert collector.name == CASES[name].collector
    dataset = DemoDataset("local/replay", tmp_path / "ds", suite.config)
    collect_fresh(suite, dataset, dict.fromkeys(suite.tasks, 1), seed=3, round_index=0, source="initial")
    meta = read_episode_metadata(tmp_path / "ds")
    assert list(meta["task"]) == suite.tasks and set(meta["adademo/collector"]) == {collector.name}
    for ep, row in meta.iterrows():
        np.testing.assert_array_equal(
            row["adademo/initial_state"], suite.sample_initial_state(row["task"], row["adademo/seed"])
        )
        ds = LeRobotDataset("local/replay", root=tmp_path / "ds", episodes=[ep])
        env_state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.environment_state"]])
        state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.state"]])
        actions = np.stack([np.asarray(x) for x in ds.hf_dataset["action"]])
        assert actions.shape[1] == suite.action_dim
        env = suite.make_env(row["task"], terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": np.asarray(row["adademo/initial_state"])})
        success = False
        for t in range(len(actions)):
            np.testing.assert_allclose(obs["environment_state"], env_state[t], atol=1e-6, rtol=0)
            np.testing.assert_allclose(obs["agent_pos"], state[t], atol=1e-6, rtol=0)
            obs, _, _, _, info = env.step(actions[t])
            success |= info["is_success"]
        assert success, f"episode {ep} ({row['task']}) does not end in success on replay"


@requires_rendering
@pytest.mark.parametrize("name", CASES)
def test_pixels_state_adds_a_camera_image_and_keeps_the_state_exact(name):
    from adademo_lerobot.dataset.features import dataset_features

    case = CASES[name]
    pix = make_suite(case.config(tasks=case.pixel_task, obs_type="pixels_state", image_size=32))
    assert dataset_features(pix)["observation.images.default"]["shape"] == (32, 32, 3)
    task = pix.tasks[0]
    obs, _ = pix.make_env(task).reset(seed=4)
    image = obs["pixels"]["default"]
    assert image.shape == (32, 32, 3) and image.dtype == np.uint8 and image.std() > 1.0
    # Rendering does not touch the simulation: the state matches a state-only env step for step.
    env = pix.make_env(task)
    obs, _ = env.reset(seed=4)
    state_env = make_suite(case.config(tasks=case.pixel_task)).make_env(task)
    state_obs, _ = state_env.reset(seed=4)
    for action in _actions(pix, 5):
        np.testing.assert_array_equal(obs["environment_state"], state_obs["environment_state"])
        obs, *_ = env.step(action)
        state_obs, *_ = state_env.step(action)
    assert not np.array_equal(obs["pixels"]["default"], image)  # the robot moved
    # State-only envs render frames on demand (videos of lerobot-eval).
    frame = state_env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8 and frame.std() > 1.0


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
def test_one_adademo_expand_round(name, tmp_path):
    """The same commands work unchanged on every suite: collect, train a weak ACT, expand one round."""
    from adademo_lerobot.dataset.ledger import read_ledger

    case = CASES[name]
    root = tmp_path / name
    common = [f"--dataset.repo_id=local/{name}", f"--dataset.root={root}"]
    run_cli(
        "adademo-collect",
        f"--suite.type={name}",
        f"--suite.tasks={case.expand_tasks}",
        f"--episodes_per_task={case.expand_demos}",
        *common,
    )
    run_cli("adademo-train", *common, *TINY_ACT, "--steps=2", f"--output_dir={tmp_path / 'train'}")
    ckpt = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    run_cli(
        "adademo-expand",
        *common,
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=1",
        f"--strategy.max_demos_per_task={case.expand_demos}",
        "--eval.batch_size=2",
    )
    eps = read_episode_metadata(root)
    ledger = read_ledger(root)
    assert sorted(r["task"] for r in ledger) == sorted(set(eps.task))
    for r in ledger:
        assert (
            r["demos_added"]
            == int(((eps.task == r["task"]) & (eps["adademo/round"] == 1)).sum())
            <= case.expand_demos
        )
        assert r["eval_episodes"] == r["successes"] + r["failures"]
