"""`--suite.type=lerobot_env`: any LeRobot simulation env as a suite, built by LeRobot's own `EnvConfig` registry and
`make_env` (the built-in `--env.type`s and every installed `lerobot_env_*` plugin).

    --suite.type=lerobot_env --suite.env.type=so101 --suite.env.random_block_position=true \\
        --suite.tasks=SO101PickPlace-v0

Principle B needs two things of an env: a way to start again from a given initial state, and an expert. Here the
initial state is the env's **reset seed**: `adademo/initial_state` is `[1, seed]` (the 1 marks "a reset seed";
seeds stay below 2**52 so that float64 holds them exactly), and the episode restarts with `reset(seed=seed)`.
That is only a restore if the env is deterministic under its seed, so a suite is accepted only after two resets
with the same seed (another seed in between) gave the same first observation, and refused in one line otherwise.
The expert is a controller shipped with the env's package (`--collector.type=callable`), a LeRobot checkpoint
(`--collector.type=policy`), or a person (`adademo-record`).

Observations follow the env's own `agent_pos` and `environment_state` (LeRobot's convention); the task one-hot is
appended to `environment_state`, as in every suite. Actions are clipped to the env's own action box. Success is
read from the step's info: `is_success` (LeRobot's convention), else `success` or `succeed` (plugins differ).
An episode ends at success (evaluation), at the step limit, or when the env itself ends it (e.g. a block pushed
out of the workspace). The whole state at an arbitrary step is not captured for an env we do not know: corrections
(`--demo_start=takeover`) are refused on this suite.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import (
    SuiteBase,
    SuiteConfig,
    SuiteTaskEnv,
    check_common_config,
    split_task_list,
)
from adademo_lerobot.suites.lerobot_env_build import (
    build_env,
    canonical_task,
    check_deterministic,
    check_spaces,
    env_config,
    env_fields,
    resolve_tasks,
)

log = logging.getLogger(__name__)

SEED_KIND = 1.0  # the first value of this suite's initial states: "the rest is a reset seed"
SEED_RANGE = 2**52  # float64 holds every integer below it exactly
SUCCESS_KEYS = ("is_success", "success", "succeed")
_NOTED: set[str] = set()


@SuiteConfig.register_subclass("lerobot_env")
@dataclass
class LeRobotEnvSuiteConfig(SuiteConfig):
    # The LeRobot env: --suite.env.type=NAME and its fields (e.g. --suite.env.random_block_position=true), any
    # `--env.type` of lerobot-eval or an installed `lerobot_env_*` plugin. Kept whole with the dataset.
    env: dict = field(default_factory=dict)
    # Episode step limit; 0: the env's own (its config's `episode_length`).
    max_episode_steps: int = 0

    @classmethod
    def suite_class(cls) -> type[LeRobotEnvSuite]:
        return LeRobotEnvSuite

    def canonical(self) -> LeRobotEnvSuiteConfig:
        env = env_config(self.env)
        steps = self.max_episode_steps or int(getattr(env, "episode_length", 0) or 300)
        tasks = ",".join(canonical_task(env, t) for t in split_task_list(self.tasks))
        return dataclasses.replace(self, env=env_fields(env), max_episode_steps=steps, tasks=tasks)


class LeRobotEnvTaskEnv(SuiteTaskEnv):
    """One task of a LeRobot env: its own observation (`agent_pos`, `environment_state` + task one-hot), its own
    action box, its seed as the initial state."""

    def __init__(self, suite: LeRobotEnvSuite, task: str, terminate_on_success: bool = True):
        super().__init__(suite, task, terminate_on_success)
        self._raw = build_env(suite.env_config, task)
        self.action_space = self._raw.action_space
        self.raw_observation: dict | None = None  # the env's own last observation (what its controllers read)
        self._env_ended = False

    def _restore(self, state: np.ndarray) -> dict:
        if state.shape != (2,) or state[0] != SEED_KIND:
            raise AdaDemoError(
                f"a lerobot_env initial state is [1, seed] (a reset seed), got {state.size} values; was it "
                "recorded for another suite?"
            )
        obs, _ = self._raw.reset(seed=int(state[1]))
        self._env_ended = False
        return obs

    def _raw_step(self, action: np.ndarray):
        obs, reward, terminated, truncated, info = self._raw.step(action)
        self._env_ended = bool(terminated or truncated)
        return obs, reward, any(bool(info.get(k, False)) for k in SUCCESS_KEYS)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        if self._env_ended and not (terminated or truncated):  # the env ended the episode (not a success)
            truncated = True
            info["final_info"] = {"is_success": info["is_success"], "task": self.task}
            self._final_obs = obs
        return obs, reward, terminated, truncated, info

    def _observation(self, raw: dict) -> dict:
        self.raw_observation = raw
        env_state = np.asarray(raw.get("environment_state", np.zeros(0)), np.float64).ravel()
        return {
            "agent_pos": np.asarray(raw["agent_pos"], np.float64).ravel(),
            "environment_state": np.concatenate([env_state, self._onehot]),
        }

    def get_state(self) -> np.ndarray:
        raise AdaDemoError(
            "the lerobot_env suite restores initial states by reset seed only, not the whole state at any step: "
            "corrections (--demo_start=takeover) need a suite that does (metaworld, fetch, adroit)"
        )

    def render(self):
        return np.ascontiguousarray(self._raw.render())


class LeRobotEnvSuite(SuiteBase):
    name = "lerobot_env"
    env_class = LeRobotEnvTaskEnv
    restores_any_state = False  # initial states only, by reset seed

    def __init__(self, config: LeRobotEnvSuiteConfig):
        if config.obs_type != "state":
            raise AdaDemoError(
                "--suite.type=lerobot_env takes the env's state observations (`agent_pos`, `environment_state`); "
                "camera images are not supported on this suite yet: --suite.obs_type=state"
            )
        self.env_config = env_config(config.env)
        canonical = config.canonical()
        config.env, config.max_episode_steps = canonical.env, canonical.max_episode_steps
        check_common_config(config)
        tasks = resolve_tasks(self.env_config, split_task_list(config.tasks))
        self._set_tasks(config, tasks)
        self.fps = int(getattr(self.env_config, "fps", 30))
        for task in tasks:
            env = build_env(self.env_config, task)
            try:
                name = f"the {self.env_config.type} env, task {task},"
                check_spaces(env, name)
                spaces = env.observation_space.spaces
                dims = (
                    int(np.prod(spaces["agent_pos"].shape)),
                    int(np.prod(spaces["environment_state"].shape)) if "environment_state" in spaces else 0,
                    int(np.prod(env.action_space.shape)),
                )
                if task == tasks[0]:
                    self.state_dim, self.layout_dim, self.action_dim = dims
                elif dims != (self.state_dim, self.layout_dim, self.action_dim):
                    raise AdaDemoError(
                        f"{name} has other observation or action sizes than {tasks[0]} (agent_pos, "
                        f"environment_state, action: {dims} against {self.state_dim, self.layout_dim, self.action_dim}):"
                        " one dataset holds tasks of the same sizes; collect them separately"
                    )
                check_deterministic(env, f"the {self.env_config.type} env, task {task}")
            finally:
                env.close()

    def sample_initial_state(self, task: str, seed: int) -> np.ndarray:
        self._check_task(task)
        return np.array([SEED_KIND, float(int(seed) % SEED_RANGE)], dtype=np.float64)

    def task_description(self, task: str) -> str:
        return task
