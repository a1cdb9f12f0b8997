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

import copy
import dataclasses
import inspect
import logging
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.suites.base import (
    SuiteBase,
    SuiteConfig,
    SuiteTaskEnv,
    check_common_config,
    check_task_names,
    split_task_list,
)

log = logging.getLogger(__name__)

SEED_KIND = 1.0  # the first value of this suite's initial states: "the rest is a reset seed"
SEED_RANGE = 2**52  # float64 holds every integer below it exactly
SUCCESS_KEYS = ("is_success", "success", "succeed")
DETERMINISM_SEEDS = (12345, 777)
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
        return dataclasses.replace(self, env=env_fields(env), max_episode_steps=steps)


def env_config(fields: dict):
    """LeRobot's `EnvConfig` of `fields["type"]` (plugins discovered as LeRobot does), with the other fields."""
    import draccus
    from lerobot.envs.configs import EnvConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    kind = fields.get("type")
    known = sorted(EnvConfig.get_known_choices())
    if not kind:
        raise AdaDemoError(f"--suite.env.type is required: a LeRobot env type ({', '.join(known)})")
    try:
        cls = EnvConfig.get_choice_class(kind)
    except KeyError:
        raise AdaDemoError(
            f"unknown --suite.env.type={kind!r}: LeRobot knows {', '.join(known)} (a plugin is found when its "
            "distribution, named lerobot_env_*, is installed)"
        ) from None
    values = {k: v for k, v in fields.items() if k != "type"}
    unknown = sorted(set(values) - {f.name for f in dataclasses.fields(cls) if f.init})
    if unknown:
        raise AdaDemoError(f"--suite.env.{unknown[0]} is not a field of LeRobot's {kind} env config")
    try:
        return draccus.decode(cls, values)
    except Exception as err:  # noqa: BLE001  (draccus raises several types for a value it cannot decode)
        raise AdaDemoError(f"--suite.env: {' '.join(str(err).split())[:300]}") from None


def env_fields(cfg) -> dict:
    """An env config as the dict stored with the dataset (every field, JSON values)."""
    import json

    import draccus

    encoded = draccus.encode(cfg)
    skip = {"features", "features_map"}  # LeRobot's feature descriptions, derived from the type
    return {
        "type": cfg.type,
        **{k: v for k, v in json.loads(json.dumps(encoded, default=str)).items() if k not in skip},
    }


def env_tasks(cfg) -> list[str]:
    """The tasks the env's package registers with gymnasium (its `task` values), else just its config's task."""
    namespace = getattr(cfg, "package_name", None)
    registered = sorted(
        spec.id.split("/", 1)[1]
        for spec in gym.registry.values()
        if namespace and spec.namespace == namespace
    )
    return registered or [t for t in [getattr(cfg, "task", None)] if t]


def build_env(cfg, task: str) -> gym.Env:
    """One env of `task`, made by LeRobot's `make_env` (a sub-env of its vector env, without the step limit:
    the suite ends episodes itself). A config whose `gym_kwargs` the env's constructor does not take (a plugin's
    config shared by several tasks) is retried without those arguments, with a note."""
    from lerobot.envs.factory import make_env

    cfg = copy.deepcopy(cfg)
    if hasattr(cfg, "task"):
        cfg.task = task
    try:
        vector = next(iter(next(iter(make_env(cfg, n_envs=1, use_async_envs=False).values())).values()))
        env = vector.envs[0]
    except TypeError as err:
        if "unexpected keyword argument" not in str(err) or not hasattr(cfg, "gym_id"):
            raise
        spec = gym.spec(cfg.gym_id)
        accepted = inspect.signature(gym.envs.registration.load_env_creator(spec.entry_point)).parameters
        kwargs = {k: v for k, v in cfg.gym_kwargs.items() if k in accepted or k == "max_episode_steps"}
        note = (
            f"note: the {cfg.type} env config passes {', '.join(sorted(set(cfg.gym_kwargs) - set(kwargs)))}, "
            f"which {cfg.gym_id} does not take: left out"
        )
        if note not in _NOTED:
            _NOTED.add(note)
            log.info(note)
        env = gym.make(cfg.gym_id, disable_env_checker=True, **kwargs)
    wrapper = env
    while isinstance(wrapper, gym.Wrapper):  # the suite counts steps; the env's own limit must not cut first
        if isinstance(wrapper, gym.wrappers.TimeLimit):
            wrapper._max_episode_steps = 10**9
        wrapper = wrapper.env
    return env


def first_observation(env: gym.Env, seed: int) -> dict:
    obs, _ = env.reset(seed=int(seed))
    return {k: np.array(v, copy=True) for k, v in obs.items() if not isinstance(v, dict)}


def check_deterministic(env: gym.Env, name: str) -> None:
    """Two resets with the same seed, another one between them, must give the same first observation."""
    a, b = DETERMINISM_SEEDS
    first = first_observation(env, a)
    first_observation(env, b)
    again = first_observation(env, a)
    if any(not np.array_equal(first[k], again[k]) for k in first):
        raise AdaDemoError(
            f"{name} is not deterministic under its reset seed: reset(seed={a}) gave two different first "
            "observations (checked before anything is written), so its seeds cannot stand for initial states; "
            "use an env whose reset(seed) fixes the layout, or one with an exact state restore"
        )
    if all(np.array_equal(first[k], first_observation(env, b)[k]) for k in first):
        log.info(
            "note: %s starts every episode the same whatever the seed: AdaDemo has no initial states to choose "
            "(enable the env's randomization, e.g. --suite.env.random_block_position=true)",
            name,
        )


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
        known = env_tasks(self.env_config)
        tasks = split_task_list(config.tasks) or known[:1]
        check_task_names(tasks, known, f"{self.env_config.type} env")
        self._set_tasks(config, tasks)
        self.fps = int(getattr(self.env_config, "fps", 30))
        probe = build_env(self.env_config, tasks[0])
        try:
            spaces = probe.observation_space
            if "agent_pos" not in spaces.spaces:
                raise AdaDemoError(
                    f"the {self.env_config.type} env observes no `agent_pos`: this suite needs LeRobot's state keys"
                )
            self.state_dim = int(np.prod(spaces["agent_pos"].shape))
            self.layout_dim = (
                int(np.prod(spaces["environment_state"].shape)) if "environment_state" in spaces.spaces else 0
            )
            self.action_dim = int(np.prod(probe.action_space.shape))
        finally:
            probe.close()
        for task in tasks:
            env = build_env(self.env_config, task)
            try:
                check_deterministic(env, f"the {self.env_config.type} env, task {task}")
            finally:
                env.close()

    def sample_initial_state(self, task: str, seed: int) -> np.ndarray:
        self._check_task(task)
        return np.array([SEED_KIND, float(int(seed) % SEED_RANGE)], dtype=np.float64)

    def task_description(self, task: str) -> str:
        return task
