"""Gymnasium-robotics Adroit (v1) as a task suite: Door, Hammer, Pen, Relocate with exact initial states.

**Initial state.** An Adroit initial state is the env's own state dict (`get_env_state()`), restricted to the
keys its `set_env_state` accepts (the keys of `env.unwrapped._state_space.spaces`, in that order; Hammer's
`get_env_state()` also returns `target_pos`, which `set_env_state` rejects) and flattened into one float64
vector:

    door      door_body_pos (3), qpos (30), qvel (30)                 = 63
    hammer    board_pos (3), qpos (33), qvel (33)                     = 69
    pen       desired_orien (4, target quaternion), qpos (30), qvel (30) = 64
    relocate  obj_pos (3), qpos (36), qvel (36), target_pos (3)       = 78

so anyone can restore it with the stock env: split the vector by those shapes and call
`env.reset(options={"initial_state_dict": d})`. Sampling is the stock env's own `reset(seed=seed)`, captured.
A restore is `reset(seed=0, options={"initial_state_dict": d})` (the env's own reset clears `MjData` with
`mj_resetData`; its random model edits are then overwritten by `set_env_state`), and for Pen the pen and target
lengths are recomputed from the restored model as its `reset_model` does, so a restore equals the stock env's
`reset(seed=k)` step for step and does not depend on the env's history.

**Unified action (30-D, the paper's appendix).** 6-D root motion + 24 hand joints, in Relocate's actuator order
(the full Adroit platform): 0:3 `A_ARTx/y/z` (arm translation), 3:6 `A_ARRx/y/z` (arm rotation), 6:8 `A_WRJ1/0`
(wrist), 8:12 `A_FFJ3..0`, 12:16 `A_MFJ3..0`, 16:20 `A_RFJ3..0`, 20:25 `A_LFJ4..0`, 25:30 `A_THJ4..0`. Each
dimension is that actuator's normalized command in [-1, 1] (the env maps it to its own ctrlrange). Each task's
native action is read from its model's actuator names (`native_from_unified`):

    relocate  all 30 dims (identity)
    door      28: dims 2:30 (A_ARTz, A_ARRx, A_ARRy, A_ARRz + 24 hand); dims 0, 1 (ARTx, ARTy) are ignored
    hammer    26: dims 3, 4 (A_ARRx, A_ARRy) + 6:30; dims 0, 1, 2, 5 are ignored
    pen       24: dims 6:30 (hand only); dims 0:6 are ignored

**Observations.** `agent_pos` (state_dim 30) is the joint positions of the same 30 joints, in the action's
order (zero for joints the task does not have). `environment_state` is one 92-D layout for all four tasks +
the task one-hot: the 30 joint positions, then one block per task holding that task's own observation after its
joint entries (the other tasks' blocks are zero), so every value of the native observation sits at a fixed
index (`native_obs_indices(task)`):

    0:30   joint positions (= agent_pos)
    30:42  door      latch, door hinge, palm xyz, handle xyz, palm - handle, door open (+1 / -1)
    42:62  hammer    nail joint, hammer velocity (6, clipped to +-1), palm xyz, hammer xyz, hammer euler,
                     nail xyz, nail impact sensor
    62:83  pen       pen xyz, pen velocity (6), pen direction, target direction, pen - target xyz,
                     pen direction - target direction
    83:92  relocate  palm - ball, palm - target, ball - target

**Success (DAPG's `evaluate_success`).** The env reports per step whether its goal is achieved
(`info["success"]`: door hinge >= 1.35 rad; nail within 1 cm of the goal; pen within 7.5 cm of the target
position with orientation similarity > 0.95; ball within 10 cm of the target). An episode succeeds when the
goal is achieved on more than 25 steps (door, hammer, relocate) or more than 20 steps (pen) of the episode:
`SUCCESS_STEPS` = 26 / 26 / 21 / 26 goal-achieved steps, not necessarily consecutive. `info["is_success"]`
becomes True at the step where the count reaches that number and stays True; with `terminate_on_success` the
episode ends there. `info["goal_achieved"]` is the env's own per-step flag. Step limits are the envs' own
`max_episode_steps`: 200 for all four in gymnasium-robotics 1.4.2 (DAPG used 100 for Pen), the default of
`--suite.max_episode_steps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.adroit_rewards import reward_function
from adademo_lerobot.suites.base import SuiteConfig
from adademo_lerobot.suites.gym_robotics import (
    DEFAULT_CAMERA,
    GymRoboticsSuite,
    GymRoboticsTaskEnv,
    checked_state,
    make_raw_env,
)
from adademo_lerobot.suites.mujoco_rollouts import BatchedRollouts

# Canonical task names (stored in config.tasks, one-hot order follows the requested order) and short aliases.
TASKS = ["AdroitHandDoor-v1", "AdroitHandHammer-v1", "AdroitHandPen-v1", "AdroitHandRelocate-v1"]
SHORT_NAMES = {
    "door": "AdroitHandDoor-v1",
    "hammer": "AdroitHandHammer-v1",
    "pen": "AdroitHandPen-v1",
    "relocate": "AdroitHandRelocate-v1",
}
DESCRIPTIONS = {
    "AdroitHandDoor-v1": "Undo the latch and swing the door open.",
    "AdroitHandHammer-v1": "Pick up the hammer and drive the nail into the board.",
    "AdroitHandPen-v1": "Reorient the pen in the hand to match the target orientation.",
    "AdroitHandRelocate-v1": "Pick up the ball and move it to the target position.",
}
# The unified 30-D action: 6 root (arm) actuators + 24 hand actuators (wrist 2, fingers 22), Relocate's order.
UNIFIED_ACTUATORS = (
    "A_ARTx", "A_ARTy", "A_ARTz", "A_ARRx", "A_ARRy", "A_ARRz", "A_WRJ1", "A_WRJ0",
    "A_FFJ3", "A_FFJ2", "A_FFJ1", "A_FFJ0", "A_MFJ3", "A_MFJ2", "A_MFJ1", "A_MFJ0",
    "A_RFJ3", "A_RFJ2", "A_RFJ1", "A_RFJ0", "A_LFJ4", "A_LFJ3", "A_LFJ2", "A_LFJ1", "A_LFJ0",
    "A_THJ4", "A_THJ3", "A_THJ2", "A_THJ1", "A_THJ0",
)  # fmt: skip
UNIFIED_JOINTS = tuple(name[2:] for name in UNIFIED_ACTUATORS)  # each actuator drives the joint of its name
ACTION_DIM = len(UNIFIED_ACTUATORS)  # 30
ROOT_DIM = 6
JOINT_DIM = len(UNIFIED_JOINTS)  # 30: agent_pos
# Per task: how many leading entries of its native observation are joint positions of the unified joints, and
# where the rest of its native observation sits in the 92-D layout.
NATIVE_JOINT_OBS = {
    "AdroitHandDoor-v1": 27,
    "AdroitHandHammer-v1": 26,
    "AdroitHandPen-v1": 24,
    "AdroitHandRelocate-v1": 30,
}
TASK_BLOCKS = {
    "AdroitHandDoor-v1": (30, 12),
    "AdroitHandHammer-v1": (42, 20),
    "AdroitHandPen-v1": (62, 21),
    "AdroitHandRelocate-v1": (83, 9),
}  # (start, size)
OBS_DIM = 92
# DAPG: an episode succeeds when the goal is achieved on more than 25 (pen: 20) of its steps.
SUCCESS_STEPS = {
    "AdroitHandDoor-v1": 26,
    "AdroitHandHammer-v1": 26,
    "AdroitHandPen-v1": 21,
    "AdroitHandRelocate-v1": 26,
}
FPS = 100  # Adroit: timestep 0.002 s x frame_skip 5 = dt 0.01 s
RESTORE_SEED = (
    0  # the env's own random draw during a restore is overwritten; a fixed seed keeps it history-free
)


@SuiteConfig.register_subclass("adroit")
@dataclass
class AdroitSuiteConfig(SuiteConfig):
    # The Adroit envs' own TimeLimit (gymnasium-robotics 1.4.2: 200 steps at 100 Hz for all four tasks).
    max_episode_steps: int = 200
    # `default`: the env's own free camera (what `env.render()` shows); or a camera of the model: `fixed`,
    # `vil_camera` (all tasks), `view_1`..`view_5` (pen only).
    camera: str = DEFAULT_CAMERA

    @classmethod
    def suite_class(cls) -> type[AdroitSuite]:
        return AdroitSuite


def native_from_unified(raw_env) -> np.ndarray:
    """Index array: native action = unified action[index], read from the model's actuator names."""
    model = raw_env.model
    names = [model.actuator(i).name for i in range(model.nu)]
    unknown = [n for n in names if n not in UNIFIED_ACTUATORS]
    if unknown:
        raise AdaDemoError(f"actuators {unknown} are not part of the unified Adroit action")
    return np.array([UNIFIED_ACTUATORS.index(n) for n in names], dtype=np.int64)


def joint_qpos_addresses(raw_env) -> tuple[np.ndarray, np.ndarray]:
    """(indices into the 30 unified joints, their qpos addresses) for the joints this task's model has."""
    model = raw_env.model
    slots, addresses = [], []
    for k, name in enumerate(UNIFIED_JOINTS):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid >= 0:
            slots.append(k)
            addresses.append(int(model.jnt_qposadr[jid]))
    return np.array(slots, dtype=np.int64), np.array(addresses, dtype=np.int64)


def native_obs_indices(task: str) -> np.ndarray:
    """Indices of the 92-D layout holding the task's native observation: `layout[idx] == native obs`."""
    raw = make_raw_env(task)
    joints = native_from_unified(raw)  # the observation's joint entries follow the actuator order ...
    if task == "AdroitHandDoor-v1":
        joints = joints[1:]  # ... except Door's, which leaves out ARTz (qpos[1:-2])
    joints = joints[: NATIVE_JOINT_OBS[task]]
    start, size = TASK_BLOCKS[task]
    raw.close()
    return np.concatenate([joints, np.arange(start, start + size)])


def state_shapes(raw_env) -> dict[str, tuple[int, ...]]:
    return {key: space.shape for key, space in raw_env._state_space.spaces.items()}


def state_dim_of(raw_env) -> int:
    return int(sum(np.prod(shape) for shape in state_shapes(raw_env).values()))


def capture_state(raw_env) -> np.ndarray:
    """`get_env_state()` restricted to the keys `set_env_state` takes, flattened in `_state_space` order."""
    full = raw_env.get_env_state()
    parts = [np.asarray(full[key], dtype=np.float64).ravel() for key in state_shapes(raw_env)]
    return np.array(np.concatenate(parts), dtype=np.float64, copy=True)


def state_dict_of(raw_env, state: np.ndarray) -> dict[str, np.ndarray]:
    """The flat vector back to the env's `initial_state_dict`."""
    out, offset = {}, 0
    for key, shape in state_shapes(raw_env).items():
        size = int(np.prod(shape))
        out[key] = np.array(state[offset : offset + size], dtype=np.float64).reshape(shape)
        offset += size
    return out


def restore_state(raw_env, state: np.ndarray) -> np.ndarray:
    """Reset to exactly `state`; returns the env's raw observation."""
    state = checked_state(state, state_dim_of(raw_env), "Adroit")
    # The env's own reset clears MjData (mj_resetData) and draws a random layout (from a fixed seed, so the
    # env's history does not matter), which set_env_state then overwrites with the recorded one.
    raw, _ = raw_env.reset(seed=RESTORE_SEED, options={"initial_state_dict": state_dict_of(raw_env, state)})
    if hasattr(raw_env, "tar_length"):
        # Pen: reset_model measured the lengths of the randomly drawn target; measure the restored one (equal
        # up to rounding), exactly as the stock env's reset(seed=k) does for its own draw.
        data = raw_env.data
        raw_env.pen_length = np.linalg.norm(
            data.site_xpos[raw_env.obj_t_site_id] - data.site_xpos[raw_env.obj_b_site_id]
        )
        raw_env.tar_length = np.linalg.norm(
            data.site_xpos[raw_env.tar_t_site_id] - data.site_xpos[raw_env.tar_b_site_id]
        )
        raw = raw_env._get_obs()
    return raw


class AdroitTaskEnv(GymRoboticsTaskEnv):
    """One Adroit task: `agent_pos` = 30 joint positions, `environment_state` = 92-D layout + task one-hot, 30-D
    unified actions (see the module docstring).

    `info["is_success"]` becomes True once the env's goal has been achieved on `SUCCESS_STEPS[task]` steps of
    the episode (and stays True); with `terminate_on_success` (evaluation) the episode ends there.
    `info["goal_achieved"]` is the env's own per-step flag.
    """

    def __init__(self, suite: AdroitSuite, task: str, terminate_on_success: bool = True):
        super().__init__(suite, task, terminate_on_success)
        self.native_index = native_from_unified(self._raw)
        self._joint_slots, self._joint_qpos = joint_qpos_addresses(self._raw)
        self._native_joints = NATIVE_JOINT_OBS[task]
        self._block = slice(TASK_BLOCKS[task][0], TASK_BLOCKS[task][0] + TASK_BLOCKS[task][1])
        self.success_steps = SUCCESS_STEPS[task]
        self._goal_steps = 0
        self._goal_achieved = False
        self._batched: dict[tuple[bool, int], BatchedRollouts] = {}

    @property
    def goal_achieved_steps(self) -> int:
        """Steps of the current episode on which the env reported its goal achieved."""
        return self._goal_steps

    def _restore(self, state: np.ndarray) -> np.ndarray:
        self._goal_steps, self._goal_achieved = 0, False
        return restore_state(self._raw, state)

    def _own_state(self) -> np.ndarray:
        return np.array([self._goal_steps, self._goal_achieved], np.float64)

    def _set_own_state(self, values: np.ndarray) -> None:
        self._goal_steps, self._goal_achieved = int(values[0]), bool(values[1])

    def _raw_step(self, action: np.ndarray):
        raw, reward, _, _, info = self._raw.step(action[self.native_index])
        self._goal_achieved = bool(info.get("success", False))
        self._goal_steps += int(self._goal_achieved)
        return raw, reward, self._goal_steps >= self.success_steps

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        info["goal_achieved"] = self._goal_achieved
        return obs, reward, terminated, truncated, info

    @property
    def used_action_dims(self) -> np.ndarray:
        """The dimensions of the 30-D unified action this task's hand has (the others are ignored)."""
        return self.native_index

    def batched_rollouts(self, shaped: bool, threads: int = 1) -> BatchedRollouts:
        """This task's rollouts in C from the current state, scored by its reward (`shaped`: the planner's, of
        the state each step reaches, see adroit_rewards; else exactly the env's own).
        """
        key = (shaped, threads)
        if key not in self._batched:
            reward_of = reward_function(self.task, self._raw, shaped)
            self._batched[key] = BatchedRollouts(
                self._raw, self.native_index, reward_of, threads, as_env_reads=not shaped
            )
        return self._batched[key]

    def close(self):
        for rollouts in self._batched.values():
            rollouts.close()
        self._batched.clear()
        super().close()

    def _layout(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        joints = np.zeros(JOINT_DIM, dtype=np.float64)
        joints[self._joint_slots] = self._raw.data.qpos[self._joint_qpos]
        layout = np.zeros(OBS_DIM, dtype=np.float64)
        layout[:JOINT_DIM] = joints
        layout[self._block] = np.asarray(raw, dtype=np.float64)[self._native_joints :]
        return joints, layout


class AdroitSuite(GymRoboticsSuite):
    """AdroitHandDoor/Hammer/Pen/Relocate v1 (short names `door`, `hammer`, `pen`, `relocate`, or `all`)."""

    name = "adroit"
    fps = FPS
    action_dim = ACTION_DIM
    state_dim = JOINT_DIM
    layout_dim = OBS_DIM
    env_class = AdroitTaskEnv
    TASKS, SHORT_NAMES, DESCRIPTIONS = TASKS, SHORT_NAMES, DESCRIPTIONS
    capture_state = staticmethod(capture_state)
