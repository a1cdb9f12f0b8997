"""MetaWorld v3 as a task suite: state observations by default, exact initial-state restore.

A MetaWorld initial state is the env's object/goal vector `_last_rand_vec`. It is captured right after a
seeded reset and restored with `_last_rand_vec = v; _freeze_rand_vec = True; reset()`, which reproduces the
observation exactly (tests/test_suite_metaworld.py checks it for every task). The goal is made observable (`_partially_observable = False`): the
goal is part of the initial state the policy must condition on, and the scripted experts read it too.
"""

from __future__ import annotations

import hashlib
import warnings
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property, partial

import mujoco
import numpy as np

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.gl import check_rendering_works
from adademo_lerobot.core.patching import temporarily_set
from adademo_lerobot.suites.base import (
    SuiteBase,
    SuiteConfig,
    SuiteTaskEnv,
    check_task_names,
    split_task_list,
)
from adademo_lerobot.suites.parsed_models import models_parsed_once

MT10 = [
    "reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3",
    "drawer-close-v3", "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3", "window-close-v3",
]  # fmt: skip
# Raw 39-D observation: hand xyz, gripper opening, two objects (pos + quat), the previous frame, goal xyz.
RAW_OBS_DIM = 39
PREV_OBS_DIM = 18  # MetaWorld's frame stacking: the previous step's hand, gripper and object part
# Task attributes MetaWorld's reward code changes during an episode (read from metaworld 3.0.0's v3 envs).
EPISODE_ATTRIBUTES = ("pickCompleted", "placeCompleted", "reachCompleted", "_target_to_obj_init")
PROPRIO_DIM = 4  # hand xyz + gripper opening: the robot's own state
ACTION_DIM = 4
# What the `adademo_sim` robot (lerobot_plugins) reads and takes, by LeRobot's motor names.
ROBOT_JOINTS = ("x.pos", "y.pos", "z.pos", "gripper.pos")
ROBOT_ACTIONS = ("x.vel", "y.vel", "z.vel", "gripper.vel")
# How a dataset's frames see the scene: `env`, LeRobot's env convention (observation.state = the hand,
# observation.environment_state = the 39-D state + task one-hot); `robot`, what the adademo_sim robot records (the
# hand as observation.state, no environment_state; with a camera); `robot_scene`, the robot with
# `--robot.scene_state=true` (the hand then the scene readings in observation.state).
VIEWS = ("env", "robot", "robot_scene")
FPS = 80
RENDER_SIZE = 256  # frames for videos of state-only envs
PRISTINE_MODEL_FIELDS = (
    "body_pos",
    "body_quat",
    "site_pos",
    "site_quat",
)  # MetaWorld: timestep 0.0025 s x frame_skip 5


@SuiteConfig.register_subclass("metaworld")
@dataclass
class MetaWorldSuiteConfig(SuiteConfig):
    camera: str = "corner2"
    # `env` (default), or the view of a dataset recorded on the adademo_sim robot: `robot` or `robot_scene`
    # (set by itself when such a dataset is continued; see VIEWS).
    view: str = "env"

    @classmethod
    def suite_class(cls) -> type[MetaWorldSuite]:
        return MetaWorldSuite

    def to_dict(self) -> dict:
        out = super().to_dict()
        if out["view"] == "env":  # as every dataset and run written before robot views stored it: unchanged
            del out["view"]
        return out


def all_task_names() -> list[str]:
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    return list(ALL_V3_ENVIRONMENTS)


def make_raw_env(task: str, render: bool = False, image_size: int = 128, camera: str = "corner2"):
    """A bare MetaWorld env with the goal observable and no internal step limit (we truncate ourselves)."""
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    kwargs = (
        {"render_mode": "rgb_array", "camera_name": camera, "width": image_size, "height": image_size}
        if render
        else {}
    )
    with warnings.catch_warnings(), models_parsed_once():
        warnings.simplefilter("ignore")
        env = ALL_V3_ENVIRONMENTS[task](**kwargs)
    env._partially_observable = False
    env.__dict__.pop("sawyer_observation_space", None)  # cached property depends on observability
    env._set_task_called = True  # we set the layout ourselves instead of through metaworld Task objects
    env.max_path_length = 10**9
    # Tasks move bodies/sites of the *model* during reset (e.g. door-open moves the door), so a reset
    # depends on the previous layout. Keep the pristine values to make every restore equal a fresh env's.
    env._adademo_pristine_model = {name: getattr(env.model, name).copy() for name in PRISTINE_MODEL_FIELDS}
    # ... and the Python-side episode state a fresh env starts with (the reward code's flags, the last stable
    # observation), which MetaWorld's reset leaves from the previous episode: a restored state must not carry it.
    env._adademo_fresh_episode = {
        name: getattr(env, name) for name in (*EPISODE_ATTRIBUTES, "_last_stable_obs") if hasattr(env, name)
    }
    env._adademo_settled_hand = SettledHandMemo()
    env.model.vis.quality.shadowsize = 0  # shadows make CPU (OSMesa) rendering ~2x slower
    if camera == "corner2":
        env.model.cam_pos[2] = [0.75, 0.075, 0.7]  # same corner2 placement as LeRobot's MetaWorld env
    return env


def hand_settling_skipped(raw_env):
    """MetaWorld's reset settles the hand with 50 physics steps per `reset_model()`; skip them, keeping the
    kinematics and `init_tcp` that reset code reads. They consume no randomness and touch no model field."""

    def kinematics_only(steps: int = 50) -> None:
        mujoco.mj_forward(raw_env.model, raw_env.data)
        raw_env.init_tcp = raw_env.tcp_center

    return temporarily_set(raw_env, "_reset_hand", kinematics_only)


class SettledHandMemo:
    """MetaWorld's `_reset_hand` (50 x 5 physics steps that move the hand to its start) remembered exactly.

    Settling is deterministic: the same model and the same simulation state going in give bit for bit the same
    `MjData` coming out. Most tasks settle the hand before placing their objects, so every restore settles from
    the same state; the memo keys on what the simulation reads (the state, the mocap targets, the body poses
    tasks edit, the hand's start) and copies the whole `MjData` back on a hit. Sites (goal markers, which tasks
    move per layout) take no part in the simulation, and reset code recomputes their world positions
    (`set_state` runs `mj_forward`) before anything reads them, so they are left out of the key; restores are
    checked equal to MetaWorld's own reset, trajectory included, for all 50 tasks (tests/test_suite_metaworld.py).
    A few recent keys are kept; tasks that settle after placing objects simply miss."""

    KEEP = 8

    def __init__(self):
        self._entries: OrderedDict[bytes, tuple[mujoco.MjData, np.ndarray]] = OrderedDict()

    @staticmethod
    def _key(raw_env, steps: int) -> bytes:
        model, data = raw_env.model, raw_env.data
        digest = hashlib.blake2b(digest_size=16)
        for array in (
            data.qpos,
            data.qvel,
            data.act,
            data.ctrl,
            data.mocap_pos,
            data.mocap_quat,
            data.qacc_warmstart,
            np.asarray(data.time),
            np.asarray(raw_env.hand_init_pos, np.float64),
            np.asarray(steps),
            model.body_pos,
            model.body_quat,
        ):
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.digest()

    def settle(self, raw_env, steps: int = 50) -> None:
        key = self._key(raw_env, steps)
        hit = self._entries.get(key)
        if hit is not None:
            self._entries.move_to_end(key)
            mujoco.mj_copyData(raw_env.data, raw_env.model, hit[0])
            raw_env.init_tcp = hit[1].copy()
            return
        type(raw_env)._reset_hand(raw_env, steps)  # MetaWorld's own settling
        snapshot = mujoco.MjData(raw_env.model)
        mujoco.mj_copyData(snapshot, raw_env.model, raw_env.data)
        self._entries[key] = (snapshot, np.array(raw_env.init_tcp, copy=True))
        while len(self._entries) > self.KEEP:
            self._entries.popitem(last=False)


def sample_layout(raw_env, seed: int) -> np.ndarray:
    """Let the env draw its own valid layout from `seed` (some tasks resample until objects do not overlap).

    The draw is MetaWorld's own `reset()` without hand settling: the same layout as a full reset's, at a fraction
    of the cost. The env is left unsettled: restore a layout before stepping it.
    """
    raw_env._freeze_rand_vec = False
    raw_env.seeded_rand_vec = True
    raw_env.seed(int(seed))
    with hand_settling_skipped(raw_env):
        raw_env.reset()
    raw_env._freeze_rand_vec = True
    return np.array(raw_env._last_rand_vec, dtype=np.float64, copy=True)


def restore_layout(raw_env, layout: np.ndarray) -> np.ndarray:
    """Reset to exactly `layout`; returns the raw observation."""
    layout = np.asarray(layout, dtype=np.float64)
    if raw_env._random_reset_space is not None and layout.shape != raw_env._random_reset_space.low.shape:
        raise AdaDemoError(
            f"initial state has {layout.size} values but this MetaWorld task needs "
            f"{raw_env._random_reset_space.low.size}; was it recorded for another task?"
        )
    # Clear model edits, solver warm-start and other history: a restore equals a fresh env's first reset.
    for name, value in raw_env._adademo_pristine_model.items():
        getattr(raw_env.model, name)[:] = value
    raw_env._last_rand_vec = layout.copy()
    raw_env._freeze_rand_vec = True
    raw_env._did_see_sim_exception = False
    for name, value in raw_env._adademo_fresh_episode.items():
        setattr(raw_env, name, value)
    # MetaWorld's reset() runs reset_model() twice: the first pass only matters through the model fields it edits
    # (mj_resetData then wipes its simulation), so it runs without hand settling, on reset data so that those edits
    # cannot depend on the previous episode; the second pass is the real one.
    # Same state as reset() (checked against it for every task in tests/test_suite_metaworld.py), half the cost.
    raw_env.curr_path_length = 0
    mujoco.mj_resetData(raw_env.model, raw_env.data)
    with hand_settling_skipped(raw_env):
        raw_env.reset_model()
    mujoco.mj_resetData(raw_env.model, raw_env.data)
    with temporarily_set(raw_env, "_reset_hand", partial(raw_env._adademo_settled_hand.settle, raw_env)):
        obs = raw_env.reset_model()
    raw_env._prev_obs = obs[:18].copy()
    obs[18:36] = raw_env._prev_obs
    return obs.astype(np.float64)


def _encode_attribute(raw_env, name: str) -> float:
    value = getattr(raw_env, name, None)
    return np.nan if value is None else float(value)


class MetaWorldTaskEnv(SuiteTaskEnv):
    """One MetaWorld task: `agent_pos` = hand xyz + gripper, `environment_state` = 39-D state + task one-hot."""

    def __init__(self, suite: MetaWorldSuite, task: str, terminate_on_success: bool = True):
        super().__init__(suite, task, terminate_on_success)
        self._raw = make_raw_env(task, self._pixels, suite.config.image_size, self._camera)
        self._renderer = None
        self._scene_in_state = suite.config.view == "robot_scene"

    def _restore(self, state: np.ndarray) -> np.ndarray:
        return restore_layout(self._raw, state)

    def _raw_step(self, action: np.ndarray):
        raw, reward, _, _, info = self._raw.step(action)
        return raw, reward, bool(info.get("success", 0.0))

    def _observation(self, raw: np.ndarray) -> dict:
        env_state = np.concatenate([raw.astype(np.float64), self._onehot])
        hand = raw[:PROPRIO_DIM].astype(np.float64)
        obs = {
            "agent_pos": np.concatenate([hand, env_state]) if self._scene_in_state else hand,
            "environment_state": env_state,  # the expert's input in every view
        }
        if self._pixels:
            obs["pixels"] = self._camera_image()
        return obs

    def _camera_image(self) -> dict:
        image = self._raw.render()
        if self._camera == "corner2":
            image = np.flip(image, (0, 1))  # this camera renders upside down (as in LeRobot's env)
        return {self._camera: np.ascontiguousarray(image)}

    def _own_state(self) -> np.ndarray:
        raw = self._raw
        stable = raw._last_stable_obs
        flags = [_encode_attribute(raw, name) for name in EPISODE_ATTRIBUTES]
        return np.concatenate(
            [
                [raw.curr_path_length, raw._did_see_sim_exception, stable is not None, *flags],
                raw._prev_obs,
                np.zeros(RAW_OBS_DIM) if stable is None else stable,
            ]
        ).astype(np.float64)

    def _set_own_state(self, values: np.ndarray) -> None:
        raw, n = self._raw, len(EPISODE_ATTRIBUTES)
        raw.curr_path_length = int(values[0])
        raw._did_see_sim_exception = bool(values[1])
        for name, value in zip(EPISODE_ATTRIBUTES, values[3 : 3 + n], strict=True):
            if hasattr(raw, name):
                kind = bool if name.endswith("Completed") else float
                setattr(raw, name, None if np.isnan(value) else kind(value))
        raw._prev_obs = values[3 + n : 3 + n + PREV_OBS_DIM].copy()
        raw._last_stable_obs = values[3 + n + PREV_OBS_DIM :].copy() if values[2] else None
        for site in raw._target_site_config:  # as MetaWorld's step does after simulating
            raw._set_pos_site(*site)

    def render(self):
        """An RGB frame for videos (e.g. `lerobot-eval`), also for state-only envs (rendered on demand)."""
        if self._pixels:
            image = self._raw.render()
        else:
            if self._renderer is None:
                check_rendering_works()
                self._renderer = mujoco.Renderer(self._raw.model, RENDER_SIZE, RENDER_SIZE)
            self._renderer.update_scene(self._raw.data, camera=self._camera)
            image = self._renderer.render()
        return np.ascontiguousarray(np.flip(image, (0, 1)) if self._camera == "corner2" else image)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
        super().close()


class MetaWorldSuite(SuiteBase):
    """Any MetaWorld v3 task, plus the group names `mt10` and `mt50`."""

    name = "metaworld"
    fps = FPS
    action_dim = ACTION_DIM
    state_dim = PROPRIO_DIM
    layout_dim = RAW_OBS_DIM
    env_class = MetaWorldTaskEnv

    def __init__(self, config: MetaWorldSuiteConfig):
        config = self._checked_config(config)
        if config.view not in VIEWS:
            raise AdaDemoError(f"unknown --suite.view={config.view!r}; choose one of {', '.join(VIEWS)}")
        tasks = self.canonical_task_names(split_task_list(config.tasks))
        check_task_names(tasks, all_task_names(), "metaworld")
        self._set_tasks(config, tasks)
        if config.view == "robot_scene":
            self.state_dim = PROPRIO_DIM + self.env_state_dim

    @classmethod
    def canonical_task_names(cls, tasks: list[str]) -> list[str]:
        """The groups `mt10` and `mt50` to their task ids; other names pass through (checked when built)."""
        out: list[str] = []
        for task in tasks:
            if task.lower() == "mt10":
                out.extend(MT10)
            elif task.lower() == "mt50":
                out.extend(all_task_names())
            else:
                out.append(task)
        return out

    def make_sampler_env(self, task: str):
        return make_raw_env(task)

    def sample_state(self, raw_env, seed: int) -> np.ndarray:
        return sample_layout(raw_env, seed)

    def task_description(self, task: str) -> str:
        return self._descriptions.get(task, task)

    @cached_property
    def _descriptions(self) -> dict[str, str]:
        from lerobot.envs.metaworld import TASK_DESCRIPTIONS

        return {f"{k}-v3" if not k.endswith("-v3") else k: v for k, v in TASK_DESCRIPTIONS.items()}
