"""What the two gymnasium-robotics families (Fetch, Adroit) share: making the stock env (optionally rendering
from a named camera), short task names, drawing an initial state with the env's own seeded reset, checking a
recorded state's size, and the task env and suite classes around them. Each family adds its state
capture/restore and observation layout."""

from __future__ import annotations

import contextlib
import io
import warnings

import gymnasium as gym
import mujoco
import numpy as np

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import (
    SuiteBase,
    SuiteConfig,
    SuiteTaskEnv,
    check_task_names,
    split_task_list,
)
from adademo_lerobot.suites.parsed_models import models_parsed_once

DEFAULT_CAMERA = "default"  # the env's own free camera (what `env.render()` shows)
RENDER_SIZE = 256  # frames for videos of state-only envs


def register_envs() -> None:
    with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()):
        # On import gymnasium-robotics 1.4.2 prints a notice about Adroit v1 reward versions to stderr.
        warnings.simplefilter("ignore")
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)


def env_max_episode_steps(task: str) -> int:
    """The registered env's own step limit (`gym.spec(task).max_episode_steps`)."""
    register_envs()
    return int(gym.spec(task).max_episode_steps)


def make_raw_env(task: str, render: bool = False, image_size: int = 128, camera: str = DEFAULT_CAMERA):
    """The unwrapped gymnasium-robotics env (no TimeLimit: the task env truncates itself).

    With `render` the env renders `image_size` RGB frames from `camera` (its OpenGL context is made on the first
    frame only; rendering does not touch the simulation state).
    """
    register_envs()
    kwargs = {"render_mode": "rgb_array", "width": image_size, "height": image_size} if render else {}
    with warnings.catch_warnings(), models_parsed_once():
        warnings.simplefilter("ignore")
        raw = gym.make(task, disable_env_checker=True, **kwargs).unwrapped
    if render:
        raw.model.vis.quality.shadowsize = 0  # shadows make CPU (OSMesa) rendering ~2x slower
        if camera != DEFAULT_CAMERA:  # the env's own renderer uses its free camera; swap in a named one
            if mujoco.mj_name2id(raw.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
                names = [raw.model.camera(i).name for i in range(raw.model.ncam)]
                raise AdaDemoError(
                    f"--suite.camera={camera!r} is not a camera of {task}; use default or one of {names}"
                )
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            raw.mujoco_renderer.close()
            raw.mujoco_renderer = MujocoRenderer(
                raw.model, raw.data, None, image_size, image_size, camera_name=camera
            )
    return raw


def checked_state(state: np.ndarray, expected: int, family: str) -> np.ndarray:
    """A recorded initial state as float64, refused unless it has this task's `expected` number of values."""
    state = np.asarray(state, dtype=np.float64)
    if state.shape != (expected,):
        raise AdaDemoError(
            f"initial state has {state.size} values but this {family} task needs {expected}; "
            f"was it recorded for another task?"
        )
    return state


class GymRoboticsTaskEnv(SuiteTaskEnv):
    """One task of a gymnasium-robotics family: the stock env, and LeRobot's observation dict from the family's
    layout (`_layout`: agent_pos and environment_state without the task one-hot) of each raw observation."""

    def __init__(self, suite: GymRoboticsSuite, task: str, terminate_on_success: bool = True):
        super().__init__(suite, task, terminate_on_success)
        cfg = suite.config
        # Always able to render: state-only envs render frames on demand for videos (e.g. `lerobot-eval`).
        self._raw = make_raw_env(task, True, cfg.image_size if self._pixels else RENDER_SIZE, cfg.camera)

    def _layout(self, raw) -> tuple[np.ndarray, np.ndarray]:
        """(agent_pos, environment_state without the task one-hot) of a raw observation."""
        raise NotImplementedError

    def _observation(self, raw) -> dict:
        agent_pos, layout = self._layout(raw)
        obs = {"agent_pos": agent_pos, "environment_state": np.concatenate([layout, self._onehot])}
        if self._pixels:
            obs["pixels"] = self._camera_image()
        return obs


class GymRoboticsSuite(SuiteBase):
    """A gymnasium-robotics family: subclasses set `name`, `TASKS` (canonical ids), `SHORT_NAMES`,
    `DESCRIPTIONS`, `layout_dim` (environment_state without the one-hot), `fps`, `action_dim`, `state_dim`,
    `env_class`, and implement `capture_state(raw_env)`."""

    TASKS: list[str]
    SHORT_NAMES: dict[str, str]
    DESCRIPTIONS: dict[str, str]
    layout_dim: int

    def __init__(self, config: SuiteConfig):
        config = self._checked_config(config)
        tasks = self.canonical_task_names(split_task_list(config.tasks))
        check_task_names(tasks, self.TASKS + list(self.SHORT_NAMES), self.name)
        self._set_tasks(config, tasks)
        if config.camera != DEFAULT_CAMERA:  # fail now, not when the first env is made mid-collection
            for task in tasks:
                make_raw_env(task, True, 16, config.camera).close()

    @classmethod
    def canonical_task_names(cls, tasks: list[str]) -> list[str]:
        """Short names (`push`) and the group `all` to gymnasium ids; unknown names pass through (to be refused
        with suggestions by the task check)."""
        out: list[str] = []
        for task in tasks:
            if task.lower() == "all":
                out.extend(cls.TASKS)
            else:
                out.append(cls.SHORT_NAMES.get(task.lower(), task))
        return out

    def task_description(self, task: str) -> str:
        return self.DESCRIPTIONS.get(task, task)

    def make_sampler_env(self, task: str):
        return make_raw_env(task)

    def sample_state(self, raw_env, seed: int) -> np.ndarray:
        raw_env.reset(seed=int(seed))
        return self.capture_state(raw_env)

    @staticmethod
    def capture_state(raw_env) -> np.ndarray:
        raise NotImplementedError
