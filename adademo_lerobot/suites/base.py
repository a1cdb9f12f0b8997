"""The task-suite protocol every benchmark family implements.

Longer than 400 lines: the protocol, the config registry and the one env base class (`SuiteTaskEnv`: exact
restores, full-state steps) every family builds on are one contract, read together by whoever adds a suite.

A suite knows its task list (whose order defines the task one-hot), builds one env per task, samples an
initial state from a seed and restores any recorded initial state exactly. Envs are plain gymnasium envs with
dict observations in LeRobot's env convention (`agent_pos`, `environment_state`, optional `pixels`), so
LeRobot's own `preprocess_observation` and `rollout` work on them unchanged.
"""

from __future__ import annotations

import abc
import dataclasses
import difflib
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import draccus
import gymnasium as gym
import mujoco
import numpy as np

from adademo_lerobot.core.episodes import executed_action
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.gl import check_rendering_works

OBS_TYPES = ("state", "pixels_state")
# MuJoCo's integration state (mj_getState): time, qpos, qvel, act, warm start, ctrl, applied forces, equality
# flags, mocap poses, userdata, plugin state: everything the next mj_step reads.
PHYSICS_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
FULL_STATE_FORMAT = 1
FULL_STATE_PARTS = ("initial_state", "own_state", "agent_pos", "environment_state", "physics")


@dataclass
class SuiteConfig(draccus.ChoiceRegistry, abc.ABC):
    """Which benchmark family, which tasks, which observations. Stored with every dataset.

    Each family registers its subclass (`--suite.type=metaworld|fetch|adroit`) and builds its own suite, as
    LeRobot's `ChoiceRegistry` configs do; `adademo_lerobot.suites` imports the built-in families.
    """

    # Comma-separated task names (or a group name the suite knows, e.g. `mt10`).
    tasks: str = ""
    # `state` (default, CPU-friendly) or `pixels_state` (adds a rendered camera image).
    obs_type: str = "state"
    image_size: int = 128
    # Episode step limit for evaluation and expert collection.
    max_episode_steps: int = 300

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    @classmethod
    def default_choice_name(cls) -> str | None:
        return "metaworld"

    @classmethod
    @abc.abstractmethod
    def suite_class(cls) -> type:
        """The family's suite class (its `layout_dim` is the environment_state size without the one-hot)."""

    def build(self) -> TaskSuite:
        """The suite this config describes (checks the config and the task names)."""
        return self.suite_class()(self)

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.type, **dataclasses.asdict(self)}

    def canonical(self) -> SuiteConfig:
        """The config as a built suite stores it (task groups and short names resolved), to compare a dataset's
        with flags: `--suite.tasks=mt10` is the dataset's ten task ids."""
        tasks = self.suite_class().canonical_task_names(split_task_list(self.tasks))
        return dataclasses.replace(self, tasks=",".join(tasks))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)


class TaskSuite(Protocol):
    """One benchmark family: tasks, envs, exact initial states, success and task conditioning."""

    config: SuiteConfig
    name: str
    fps: int
    action_dim: int
    state_dim: int

    @property
    def env_state_dim(self) -> int:
        """Size of `observation.environment_state` (the full state observation + the task one-hot)."""

    @property
    def tasks(self) -> list[str]:
        """Task names in one-hot order."""

    def make_env(self, task: str) -> gym.Env:
        """A gymnasium env for `task` whose `reset(options={"initial_state": s})` restores `s` exactly,
        whose `reset(seed=k)` starts from `sample_initial_state(task, k)`, whose `get_state()` captures the whole
        state at any step and `reset(options={"state": s})` restores it exactly, and whose `info["is_success"]`
        reports success."""

    def sample_initial_state(self, task: str, seed: int) -> np.ndarray:
        """A fresh initial state of `task`, a deterministic function of `seed` (float64 vector)."""

    def task_onehot(self, task: str) -> np.ndarray:
        """The task-conditioning vector: a one-hot over `tasks`."""

    def task_description(self, task: str) -> str:
        """A human-readable description of the task."""


def onehot(tasks: list[str], task: str) -> np.ndarray:
    vec = np.zeros(len(tasks), dtype=np.float64)
    vec[tasks.index(task)] = 1.0
    return vec


def split_task_list(tasks: str) -> list[str]:
    return [t.strip() for t in tasks.split(",") if t.strip()]


def check_task_names(requested: list[str], known: list[str], suite: str) -> None:
    """Fail with the closest valid names when a task is unknown."""
    if not requested:
        raise AdaDemoError(f"empty task list for suite {suite!r}: pass --suite.tasks=task1,task2")
    for task in requested:
        if task not in known:
            close = difflib.get_close_matches(task, known, n=3, cutoff=0.4)
            hint = f"; did you mean {', '.join(close)}?" if close else f"; valid tasks: {', '.join(known)}"
            raise AdaDemoError(f"unknown {suite} task {task!r}{hint}")
    duplicates = sorted({t for t in requested if requested.count(t) > 1})
    if duplicates:
        raise AdaDemoError(f"task listed twice in --suite.tasks: {', '.join(duplicates)}")


def check_obs_type(obs_type: str) -> None:
    if obs_type not in OBS_TYPES:
        raise AdaDemoError(f"unknown --suite.obs_type={obs_type!r}; choose one of {', '.join(OBS_TYPES)}")


def check_common_config(config: SuiteConfig) -> None:
    """Checks every suite shares: observation type, step limit, image size."""
    check_obs_type(config.obs_type)
    if config.max_episode_steps < 1:
        raise AdaDemoError(f"--suite.max_episode_steps must be >= 1, got {config.max_episode_steps}")
    if config.image_size < 16:
        raise AdaDemoError(f"--suite.image_size must be >= 16 pixels, got {config.image_size}")


class SuiteTaskEnv(gym.Env):
    """The episode logic every suite's env shares, on top of four simulator-specific hooks.

    Observations follow LeRobot's env convention: `agent_pos` (proprioception), `environment_state` (full state
    + task one-hot) and, for `pixels_state`, `pixels` = {camera: HxWx3 uint8}. The initial state comes from
    `reset(options={"initial_state": s})`, else from `pending_initial_state` (set per sub-env with
    `VectorEnv.set_attr`, since gymnasium passes one options dict to all), else from the seed. Actions are cast
    to float32 and clipped before stepping: exactly what is stored, so stored actions replay exactly.
    `info["is_success"]` reports success; with `terminate_on_success` (evaluation) the episode ends there.

    `get_state()` is the whole state at the current step (a flat float64 vector: the episode's initial state, the
    step counter, the env's own Python-side state, the observation and MuJoCo's integration state), and
    `reset(options={"state": s})` restores it exactly: the episode then continues as it would have. Corrections
    start from such states (the expert takes over a failed policy rollout mid-episode), as new episodes with the
    whole step limit ahead (`reset(options={"state": s, "new_episode": True})`).

    Subclasses set `self._raw` (the simulator) and implement `_restore`, `_raw_step` and `_observation`; those
    with Python-side state that changes during an episode implement `_own_state` / `_set_own_state`.
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, suite: TaskSuite, task: str, terminate_on_success: bool):
        super().__init__()
        cfg = suite.config
        self._suite = suite
        self.task = task
        self.task_description = suite.task_description(task)
        self.terminate_on_success = terminate_on_success
        self.metadata = {**self.metadata, "render_fps": suite.fps}
        self._max_episode_steps = cfg.max_episode_steps
        self._onehot = suite.task_onehot(task)
        self._pixels = cfg.obs_type == "pixels_state"
        self._camera = getattr(cfg, "camera", "camera")
        self.pending_initial_state: np.ndarray | None = None
        self.initial_state: np.ndarray | None = None
        # Batched evaluation: LeRobot's rollout() steps every sub-env until the slowest episode ends and ignores
        # the rest. With `hold_after_episode`, a sub-env whose episode is over (and that has no new initial state)
        # repeats its final observation instead of auto-resetting and simulating steps nobody reads.
        self.hold_after_episode = False
        self._final_obs: dict | None = None
        self._last_obs: dict | None = None
        self._steps = 0
        self._limit_from = 0  # the step the step limit counts from (a restored state may start a new episode)
        obs_spaces = {
            "agent_pos": gym.spaces.Box(-np.inf, np.inf, (suite.state_dim,), np.float64),
            "environment_state": gym.spaces.Box(-np.inf, np.inf, (suite.env_state_dim,), np.float64),
        }
        if self._pixels:
            shape = (cfg.image_size, cfg.image_size, 3)
            obs_spaces["pixels"] = gym.spaces.Dict({self._camera: gym.spaces.Box(0, 255, shape, np.uint8)})
        self.observation_space = gym.spaces.Dict(obs_spaces)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (suite.action_dim,), np.float32)

    # -- simulator-specific hooks -------------------------------------------------------------------------
    def _sample_state(self, seed: int) -> np.ndarray:
        return self._suite.sample_state(self._raw, seed)

    def _restore(self, state: np.ndarray):
        """Reset the simulator to exactly `state`; returns the raw observation."""
        raise NotImplementedError

    def _raw_step(self, action: np.ndarray) -> tuple[object, float, bool]:
        """Step the simulator; returns (raw observation, reward, success at this step)."""
        raise NotImplementedError

    def _observation(self, raw) -> dict:
        raise NotImplementedError

    def _own_state(self) -> np.ndarray:
        """The env's Python-side state that changes during an episode (beyond what the initial state sets)."""
        return np.zeros(0)

    def _set_own_state(self, values: np.ndarray) -> None:
        """Put back what `_own_state` captured (after the initial state and the physics are restored)."""

    def close(self):
        self._raw.close()

    def render(self):
        """An RGB frame (image_size with `pixels_state`, else the simulator's default), also for state-only envs."""
        check_rendering_works()
        return np.ascontiguousarray(self._raw.render())

    def _camera_image(self) -> dict:
        return {self._camera: self.render()}

    # -- shared episode logic -----------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if (options or {}).get("state") is not None:
            obs = self._restore_full(np.asarray(options["state"], np.float64))
            # `new_episode`: the restored state starts an episode of its own, with the whole step limit ahead (a
            # correction); otherwise the episode continues exactly, its step limit included.
            self._limit_from = self._steps if options.get("new_episode") else 0
            return self._remember(obs), {"is_success": False}
        state = (options or {}).get("initial_state")
        if state is None and self.pending_initial_state is not None:
            state, self.pending_initial_state = self.pending_initial_state, None
        if state is None and self._holding:
            return self._final_obs, {"is_success": False}
        self._final_obs = None
        if state is None:
            state = self._sample_state(seed if seed is not None else int(self.np_random.integers(2**62)))
        raw = self._restore(np.asarray(state, dtype=np.float64))
        self.initial_state = np.array(state, dtype=np.float64, copy=True)
        self._steps = self._limit_from = 0
        return self._remember(self._observation(raw)), {"is_success": False}

    def _remember(self, obs: dict) -> dict:
        self._last_obs = obs
        return obs

    # -- the whole state at any step ----------------------------------------------------------------------
    @property
    def steps(self) -> int:
        """Steps taken in the current episode."""
        return self._steps

    def get_state(self) -> np.ndarray:
        """The whole state at this step; `reset(options={"state": s})` continues the episode exactly from it."""
        if self.initial_state is None or self._last_obs is None:
            raise AdaDemoError("reset the env before get_state()")
        model, data = self._raw.model, self._raw.data
        physics = np.empty(mujoco.mj_stateSize(model, PHYSICS_STATE))
        mujoco.mj_getState(model, data, physics, PHYSICS_STATE)
        parts = [
            self.initial_state,
            np.asarray(self._own_state(), np.float64),
            np.asarray(self._last_obs["agent_pos"], np.float64),
            np.asarray(self._last_obs["environment_state"], np.float64),
            physics,
        ]
        header = [FULL_STATE_FORMAT, self._steps, *(p.size for p in parts)]
        return np.concatenate([np.asarray(header, np.float64), *parts])

    def _restore_full(self, state: np.ndarray) -> dict:
        parts = split_full_state(state)
        model, data = self._raw.model, self._raw.data
        if parts["physics"].size != mujoco.mj_stateSize(model, PHYSICS_STATE):
            raise AdaDemoError(
                f"the state has {parts['physics'].size} physics values but {self.task} has "
                f"{mujoco.mj_stateSize(model, PHYSICS_STATE)}; was it recorded for another task?"
            )
        self._restore(parts["initial_state"])  # the layout and the Python-side state a reset sets from it
        mujoco.mj_setState(model, data, parts["physics"], PHYSICS_STATE)
        mujoco.mj_forward(model, data)
        self._set_own_state(parts["own_state"])
        self.initial_state = parts["initial_state"].copy()
        self._steps, self._final_obs = full_state_step(state), None
        obs = {"agent_pos": parts["agent_pos"].copy(), "environment_state": parts["environment_state"].copy()}
        if self._pixels:
            obs["pixels"] = self._camera_image()
        return obs

    # -- within-episode snapshots (a planner's rollouts) -------------------------------------------------------
    def snapshot(self) -> tuple:
        """The current step, taken cheaply (physics, the env's Python-side state, the counters): `rewind` returns
        this env to it. Unlike `get_state` it leaves the layout out, so it holds only until the next reset."""
        model, data = self._raw.model, self._raw.data
        physics = np.empty(mujoco.mj_stateSize(model, PHYSICS_STATE))
        mujoco.mj_getState(model, data, physics, PHYSICS_STATE)
        own = np.array(self._own_state(), np.float64, copy=True)
        return physics, own, self._steps, self._limit_from, self._last_obs, self._final_obs

    def rewind(self, snapshot: tuple) -> None:
        """Back to a `snapshot` of this episode: the episode then continues exactly as it did from there."""
        physics, own, steps, limit_from, last_obs, final_obs = snapshot
        model, data = self._raw.model, self._raw.data
        mujoco.mj_setState(model, data, physics, PHYSICS_STATE)
        mujoco.mj_forward(model, data)
        self._set_own_state(own)
        self._steps, self._limit_from, self._last_obs, self._final_obs = (
            steps,
            limit_from,
            last_obs,
            final_obs,
        )

    @property
    def _holding(self) -> bool:
        return self.hold_after_episode and self._final_obs is not None

    def step(self, action):
        if self._holding:
            return self._final_obs, 0.0, False, False, {"is_success": False, "task": self.task}
        action = executed_action(action, self.action_space.low, self.action_space.high)
        raw, reward, success = self._raw_step(action)
        self._steps += 1
        terminated = success and self.terminate_on_success
        truncated = self._steps - self._limit_from >= self._max_episode_steps and not terminated
        info = {"is_success": success, "task": self.task}
        obs = self._remember(self._observation(raw))
        if terminated or truncated:
            info["final_info"] = {"is_success": success, "task": self.task}
            self._final_obs = obs
        return obs, float(reward), terminated, truncated, info


def split_full_state(state: np.ndarray) -> dict[str, np.ndarray]:
    """The parts of a `get_state()` vector, by name (also `step`, the episode step it was taken at)."""
    state = np.asarray(state, np.float64)
    n = len(FULL_STATE_PARTS)
    if state.ndim != 1 or state.size < 2 + n or int(state[0]) != FULL_STATE_FORMAT:
        raise AdaDemoError("not a state captured by get_state() (unknown format)")
    sizes = state[2 : 2 + n].astype(int)
    if state.size != 2 + n + sizes.sum():
        raise AdaDemoError(f"a get_state() vector of {state.size} values does not match its own header")
    bounds = np.cumsum([2 + n, *sizes])
    return {name: state[bounds[i] : bounds[i + 1]] for i, name in enumerate(FULL_STATE_PARTS)}


def full_state_step(state: np.ndarray) -> int:
    """The episode step a `get_state()` vector was captured at."""
    return int(state[1])


def cached_for_task(cache: dict, key, make: Callable[[], Any], keep: int, task_of=lambda key: key):
    """`cache[key]`, made on first use, keeping only the simulators of the `keep` most recently used tasks
    (dict order is use order). A MetaWorld env holds ~35 MB of model, so a cache of every task's envs costs GBs;
    keeping a few tasks avoids rebuilding envs when callers alternate between them."""
    item = cache.pop(key) if key in cache else make()
    cache[key] = item
    recent: list[str] = []
    for k in reversed(list(cache)):
        if task_of(k) not in recent and len(recent) < keep:
            recent.append(task_of(k))
    for k in [k for k in cache if task_of(k) not in recent]:
        cache.pop(k).close()
    return item


class SuiteBase:
    """What every suite does the same way: its task list (one-hot order), task checks, envs and seeded states.

    Subclasses set `env_class`, implement `make_sampler_env(task)` (a bare simulator used only to draw initial
    states) and `sample_state(raw_env, seed)`, and call `_set_tasks` from `__init__`.
    """

    env_class: type[SuiteTaskEnv]
    layout_dim: int  # environment_state without the task one-hot
    # `get_state()` / `reset(options={"state": ...})` at any step (corrections need it).
    restores_any_state = True

    @property
    def env_state_dim(self) -> int:
        return self.layout_dim + len(self._tasks)

    def make_sampler_env(self, task: str) -> Any:
        raise NotImplementedError

    def sample_state(self, raw_env: Any, seed: int) -> np.ndarray:
        """Let the simulator draw its own initial state from `seed` and capture it."""
        raise NotImplementedError

    @classmethod
    def canonical_task_names(cls, tasks: list[str]) -> list[str]:
        """The task ids that task names (and the family's group names) stand for, in one-hot order."""
        return list(tasks)

    def _checked_config(self, config: SuiteConfig) -> SuiteConfig:
        """The config, checked; camera images need rendering that works on this machine."""
        check_common_config(config)
        if config.obs_type == "pixels_state":
            check_rendering_works()
        return config

    def _set_tasks(self, config: SuiteConfig, tasks: list[str]) -> None:
        self.config = config
        self._tasks = tasks
        self.config.tasks = ",".join(tasks)  # stored canonical, in one-hot order
        self._samplers: dict[str, object] = {}

    @property
    def tasks(self) -> list[str]:
        """Task names in one-hot order."""
        return list(self._tasks)

    def make_env(self, task: str, terminate_on_success: bool = True) -> SuiteTaskEnv:
        self._check_task(task)
        return self.env_class(self, task, terminate_on_success)

    def sample_initial_state(self, task: str, seed: int) -> np.ndarray:
        self._check_task(task)
        env = cached_for_task(self._samplers, task, lambda: self.make_sampler_env(task), keep=4)
        return self.sample_state(env, seed)

    def task_onehot(self, task: str) -> np.ndarray:
        return onehot(self._tasks, task)

    def _check_task(self, task: str) -> None:
        if task not in self._tasks:
            raise AdaDemoError(f"task {task!r} is not in this suite's task list {self._tasks}")
