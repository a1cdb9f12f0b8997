"""Gymnasium-robotics Fetch (v4) as a task suite: Reach, Push, PickAndPlace, Slide with exact initial states.

A Fetch initial state is what the env randomizes at reset: the object's free-joint pose (`object0:joint`, 7
values: xyz + quaternion wxyz) followed by the 3-D goal; Reach has no object, so its state is the goal only.
Fetch's `reset` ignores options, so a state is restored by hand: the env's own `reset()` first (it clears
`MjData` with `mj_resetData` and puts back the robot's initial qpos/qvel, so nothing of the env's history
survives), then the object pose and the goal are overwritten, `mj_forward` runs and the observation is
recomputed. Sampling lets the env draw the state with `reset(seed=seed)` and captures it.

Observations use one 25-D layout for every task (the object tasks' own `observation`; Reach's 10 values sit at
the same robot indices, its object entries are zero), so a multi-task policy sees the same meaning per index:

    0:3   grip xyz              3:6   object xyz          6:9   object - grip
    9:11  finger joints         11:14 object euler         14:17 object velp (relative to grip)
    17:20 object velr           20:23 grip velp            23:25 finger joint velocities
    (velocities are multiplied by dt = 0.04 s, as in the env)

`agent_pos` (state_dim 10) is the robot's own part: indices 0:3, 9:11, 20:23, 23:25 (grip position, finger
joints, grip velocity, finger velocities). `environment_state` = 25-D observation + desired goal (3) + task
one-hot.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from adademo_lerobot.suites.base import SuiteConfig
from adademo_lerobot.suites.gym_robotics import (
    DEFAULT_CAMERA,
    GymRoboticsSuite,
    GymRoboticsTaskEnv,
    checked_state,
)

# Canonical task names (stored in config.tasks, one-hot order follows the requested order) and short aliases.
TASKS = ["FetchReach-v4", "FetchPush-v4", "FetchPickAndPlace-v4", "FetchSlide-v4"]
SHORT_NAMES = {
    "reach": "FetchReach-v4",
    "push": "FetchPush-v4",
    "pick_and_place": "FetchPickAndPlace-v4",
    "slide": "FetchSlide-v4",
}
DESCRIPTIONS = {
    "FetchReach-v4": "Move the gripper to the target position.",
    "FetchPush-v4": "Push the block to the target position on the table.",
    "FetchPickAndPlace-v4": "Pick up the block and place it at the target position (on the table or in the air).",
    "FetchSlide-v4": "Hit the puck so that it slides to the target position on the table.",
}
OBS_DIM = 25  # the object tasks' `observation`; Reach is scattered into the same layout
GOAL_DIM = 3
OBJECT_QPOS_DIM = 7
# The robot's own part of the 25-D observation: grip xyz, finger joints, grip velocity, finger velocities.
PROPRIO_INDICES = np.array([0, 1, 2, 9, 10, 20, 21, 22, 23, 24])
PROPRIO_DIM = len(PROPRIO_INDICES)
REACH_OBS_DIM = 10  # Reach's own observation is exactly the proprioception, in PROPRIO_INDICES order
ACTION_DIM = 4
FPS = 25  # Fetch: timestep 0.002 s x 20 substeps = dt 0.04 s


@SuiteConfig.register_subclass("fetch")
@dataclass
class FetchSuiteConfig(SuiteConfig):
    # The Fetch envs' own TimeLimit (50 steps at 25 Hz).
    max_episode_steps: int = 50
    # `default`: the env's own free camera (what `env.render()` shows); or a camera of the model, e.g.
    # `external_camera_0`, `head_camera_rgb`.
    camera: str = DEFAULT_CAMERA

    @classmethod
    def suite_class(cls) -> type[FetchSuite]:
        return FetchSuite


def state_dim_of(raw_env) -> int:
    return (OBJECT_QPOS_DIM if raw_env.has_object else 0) + GOAL_DIM


def capture_state(raw_env) -> np.ndarray:
    """The randomized part of the current state: object joint qpos (7, object tasks only) + goal (3)."""
    parts = []
    if raw_env.has_object:
        parts.append(raw_env._utils.get_joint_qpos(raw_env.model, raw_env.data, "object0:joint"))
    parts.append(raw_env.goal)
    return np.array(np.concatenate(parts), dtype=np.float64, copy=True)


def restore_state(raw_env, state: np.ndarray) -> dict:
    """Reset to exactly `state`; returns the env's raw dict observation."""
    state = checked_state(state, state_dim_of(raw_env), "Fetch")
    # The env's own reset clears MjData (mj_resetData: warm start, mocap, ctrl) and restores the robot's
    # initial qpos/qvel; its random object pose and goal are then overwritten.
    raw_env.reset()
    if raw_env.has_object:
        raw_env._utils.set_joint_qpos(raw_env.model, raw_env.data, "object0:joint", state[:OBJECT_QPOS_DIM])
    raw_env.goal = state[-GOAL_DIM:].copy()
    mujoco.mj_forward(raw_env.model, raw_env.data)
    return raw_env._get_obs()


def full_observation(raw_obs: np.ndarray) -> np.ndarray:
    """The 25-D layout (Reach's 10-D observation scattered to the robot indices)."""
    raw_obs = np.asarray(raw_obs, dtype=np.float64)
    if raw_obs.shape == (OBS_DIM,):
        return raw_obs.copy()
    out = np.zeros(OBS_DIM, dtype=np.float64)
    out[PROPRIO_INDICES] = raw_obs
    return out


class FetchTaskEnv(GymRoboticsTaskEnv):
    """One Fetch task: `agent_pos` = 10-D proprioception, `environment_state` = 25-D observation + goal + one-hot.

    Success is the env's own (object, or gripper for Reach, within 5 cm of the goal).
    """

    def _restore(self, state: np.ndarray) -> dict:
        return restore_state(self._raw, state)

    def _own_state(self) -> np.ndarray:
        # Fetch's action moves the mocap relative to the welded body's pose of the last forward pass, one physics
        # substep older than the state (mj_step integrates after its forward pass): keep those poses.
        data = self._raw.data
        return np.concatenate([data.xpos.ravel(), data.xquat.ravel()])

    def _set_own_state(self, values: np.ndarray) -> None:
        data = self._raw.data
        data.xpos[:] = values[: data.xpos.size].reshape(data.xpos.shape)
        data.xquat[:] = values[data.xpos.size :].reshape(data.xquat.shape)

    def _raw_step(self, action: np.ndarray):
        raw, reward, _, _, info = self._raw.step(action)
        return raw, reward, bool(info.get("is_success", 0.0))

    def _layout(self, raw: dict) -> tuple[np.ndarray, np.ndarray]:
        full = full_observation(raw["observation"])
        return full[PROPRIO_INDICES], np.concatenate([full, np.asarray(raw["desired_goal"], np.float64)])


class FetchSuite(GymRoboticsSuite):
    """FetchReach/Push/PickAndPlace/Slide v4 (short names `reach`, `push`, `pick_and_place`, `slide`, or `all`)."""

    name = "fetch"
    fps = FPS
    action_dim = ACTION_DIM
    state_dim = PROPRIO_DIM
    layout_dim = OBS_DIM + GOAL_DIM
    env_class = FetchTaskEnv
    TASKS, SHORT_NAMES, DESCRIPTIONS = TASKS, SHORT_NAMES, DESCRIPTIONS
    capture_state = staticmethod(capture_state)
