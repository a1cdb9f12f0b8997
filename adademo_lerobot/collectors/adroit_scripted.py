"""Scripted experts for the Adroit suite: state machines over the suite's observation and 30-D unified action.

Every expert keeps its own copy of the task's MuJoCo model for kinematics only: from the observed joint
positions (`agent_pos`) it computes where the grasp site `S_grasp` is (the point between palm and fingers where a
grasped object sits, 5 cm below the palm) and solves small inverse-kinematics problems for the arm. The
simulation itself is only seen through the observation. Each call of `expert_for` returns a fresh controller,
so every attempt is the same deterministic function of the initial state.

Arm control. The arm actuators are position servos with gain 500 and bias -200, so a command c holds a joint
at 2.5 c (minus gravity); the experts command `0.4 * q_desired`, add gravity compensation on the vertical
translation, a PD term on the translations (they are slow and under-damped) and an integral term on the pitch.
The hand's pitch (arm pitch `ARRx` + wrist `WRJ0`, the two axes are parallel) is held constant, so the arm
pitch works as a fast vertical axis while the wrist keeps the palm level.

- Relocate: hover above the ball with the hand open, descend until the ball sits at `S_grasp`, close fingers
  and thumb (fingers wrap the ball from the front, the thumb from behind), then carry the grasp point so the
  ball goes to the target and hold it there.
- Door: press the handle down with the open palm (and push the bar past vertical) to undo the latch, roll the
  hand 90 degrees so the closed fingers wrap the now vertical bar, pull the door along its arc about the hinge,
  let go at 0.8 rad and step back while the door swings on to its stop.
- Pen: a weak baseline (wrist tilt only, no finger gaiting); the planner (`--collector.type=planner`) is the pen's
  expert.
- Hammer: no scripted expert; the planner is the hammer's expert.

Measured success: benchmarks/results/adroit_expert_success.md.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from adademo_lerobot.collectors.base import SimulatedExpertCollector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.adroit import (
    ACTION_DIM,
    TASK_BLOCKS,
    UNIFIED_JOINTS,
    joint_qpos_addresses,
    make_raw_env,
    native_from_unified,
)

DT = 0.01  # seconds per env step
# Unified indices (see suites/adroit.py).
ARTX, ARTY, ARTZ, ARRX, ARRY, ARRZ, WRJ1, WRJ0 = range(8)
FINGER_FLEX = [9, 10, 11, 13, 14, 15, 17, 18, 19, 22, 23, 24]  # J2, J1, J0 of the four fingers
FINGER_SPREAD = [8, 12, 16, 21]  # J3 (abduction) of the four fingers
LF_METACARPAL = 20
THUMB = slice(25, 30)  # THJ4 .. THJ0
THUMB_OPEN = np.array([0.0, -1.0, 0.0, 0.0, 1.0])  # thumb beside the palm, straight
THUMB_OPPOSE = np.array([-0.25, 1.0, 1.0, -1.0, -1.0])  # under the palm, behind the grasp site


class Kinematics:
    """A private copy of one task's model: forward kinematics of S_grasp and action normalization."""

    def __init__(self, task: str):
        raw = make_raw_env(task)
        self.model = raw.model
        self.data = mujoco.MjData(self.model)
        self.slots, self.addresses = joint_qpos_addresses(raw)
        self.grasp_site_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "S_grasp")
        native = native_from_unified(raw)
        self.ctrl_low = np.zeros(ACTION_DIM)
        self.ctrl_high = np.zeros(ACTION_DIM)
        self.ctrl_low[native] = self.model.actuator_ctrlrange[:, 0]
        self.ctrl_high[native] = self.model.actuator_ctrlrange[:, 1]
        self.joint_low = np.full(ACTION_DIM, -np.inf)
        self.joint_high = np.full(ACTION_DIM, np.inf)
        for k, name in enumerate(UNIFIED_JOINTS):
            jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid >= 0:
                self.joint_low[k], self.joint_high[k] = self.model.jnt_range[jid]
        forearm = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "forearm")
        # Arm servos: force = gain * ctrl + bias * q, so ctrl = q * (-bias / gain) holds q (without load).
        self.hold_ratio = float(-self.model.actuator_biasprm[0, 1] / self.model.actuator_gainprm[0, 0])  # 0.4
        # Weight of everything the vertical translation carries, as a command offset (Relocate only).
        self.gravity_ctrl = float(
            self.model.body_subtreemass[forearm] * 9.81 / self.model.actuator_gainprm[0, 0]
        )
        raw.close()

    def grasp_site(self, q: np.ndarray) -> np.ndarray:
        """World position of S_grasp for unified joint positions `q` (30)."""
        self.data.qpos[self.addresses] = q[self.slots]
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self.grasp_site_id].copy()

    def normalize(self, ctrl: np.ndarray) -> np.ndarray:
        """Actuator commands (in their own units) to the normalized [-1, 1] action; absent dims give 0."""
        mean, half = (self.ctrl_low + self.ctrl_high) / 2, (self.ctrl_high - self.ctrl_low) / 2
        return np.clip(np.where(half > 0, (ctrl - mean) / np.where(half > 0, half, 1.0), 0.0), -1.0, 1.0)


def _rate_limit(ref: np.ndarray, goal: np.ndarray, rate: float) -> np.ndarray:
    step = goal - ref
    norm = float(np.linalg.norm(step))
    return goal.copy() if norm <= rate else ref + step * (rate / norm)


def _hand(
    action: np.ndarray, close: float, thumb_closed: np.ndarray = THUMB_OPPOSE, fingers: float = 1.0
) -> None:
    """Fingers and thumb from open (0) to closed (1), in place."""
    action[FINGER_FLEX] = -1.0 + close * (fingers + 1.0)
    action[FINGER_SPREAD] = 0.0
    action[LF_METACARPAL] = -1.0 + close
    action[THUMB] = THUMB_OPEN + close * (thumb_closed - THUMB_OPEN)


RELOCATE = TASK_BLOCKS["AdroitHandRelocate-v1"][0]


def relocate_expert(kin: Kinematics) -> Callable[[dict], np.ndarray]:
    """Hover, descend onto the ball, close, carry the ball to the target, hold."""
    pitch = -0.1  # hand pitch (arm ARRx + wrist WRJ0): palm nearly level
    tilt_nominal = 0.3  # arm pitch the vertical translation settles around
    tilt_max = 0.55
    grasp_offset = np.array([0.0, -0.01, 0.0])  # S_grasp - ball when grasping
    hover = 0.08  # height above the grasp pose while approaching
    rate, carry_rate = 0.01, 0.01  # metres per step of the reference
    close_steps, ramp, descend_timeout = 25, 10, 30
    kp, kd, tilt_ki = 2.0, 0.3, 0.03
    translation_low = kin.joint_low[[ARTX, ARTY, ARTZ]]
    translation_high = kin.joint_high[[ARTX, ARTY, ARTZ]]
    state = {"phase": "approach", "ref": None, "t": 0, "prev": None, "tilt_i": 0.0}

    def solve(q: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
        """Arm translations and pitch putting S_grasp at `target` (wrist at pitch - tilt)."""
        qq = q.copy()
        # The vertical translation settles so that the pitch stays near tilt_nominal ...
        qq[[ARTX, ARTY, ARTZ]] = 0.0
        qq[ARRX], qq[WRJ0] = tilt_nominal, pitch - tilt_nominal
        lift = float(np.clip(target[2] - kin.grasp_site(qq)[2], translation_low[1], translation_high[1]))
        # ... while the (fast) pitch puts S_grasp at the target height given the actual translation.
        qq[[ARTX, ARTY, ARTZ]] = q[[ARTX, ARTY, ARTZ]]
        tilt = float(np.clip(q[ARRX], 0.0, tilt_max))
        for _ in range(3):
            qq[ARRX], qq[WRJ0] = tilt, pitch - tilt
            z = kin.grasp_site(qq)[2]
            qq[ARRX], qq[WRJ0] = tilt + 1e-3, pitch - tilt - 1e-3
            slope = (kin.grasp_site(qq)[2] - z) / 1e-3
            tilt = float(np.clip(tilt + (target[2] - z) / slope, 0.0, tilt_max))
        qq[[ARTX, ARTY, ARTZ]] = 0.0
        qq[ARRX], qq[WRJ0] = tilt, pitch - tilt
        error = target - kin.grasp_site(qq)
        # ARTx moves S_grasp along -x, ARTy along +z, ARTz along +y (the forearm frame).
        translation = np.clip(np.array([-error[0], lift, error[1]]), translation_low, translation_high)
        return translation, tilt

    def act(observation: dict) -> np.ndarray:
        q = np.asarray(observation["agent_pos"], dtype=np.float64)
        env_state = np.asarray(observation["environment_state"], dtype=np.float64)
        palm_ball, palm_target = env_state[RELOCATE : RELOCATE + 3], env_state[RELOCATE + 3 : RELOCATE + 6]
        palm = kin.grasp_site(q)
        ball, target = palm - palm_ball, palm - palm_target
        if state["ref"] is None:
            state["ref"] = palm.copy()
        phase, close = state["phase"], 0.0
        if phase == "approach":
            goal = ball + grasp_offset + np.array([0.0, 0.0, hover])
            if np.linalg.norm(palm - goal) < 0.02:
                phase, state["t"] = "descend", 0
        if phase == "descend":
            goal = ball + grasp_offset
            state["t"] += 1
            # The arm's reach ends before some far balls: grasp from a little behind after a while.
            if np.linalg.norm(palm - goal) < 0.012 or state["t"] > descend_timeout:
                phase, state["t"] = "grasp", 0
        if phase == "grasp":
            goal = ball + grasp_offset
            state["t"] += 1
            close = min(1.0, state["t"] / ramp)
            if state["t"] >= close_steps:
                phase, state["ref"] = "carry", palm.copy()
        if phase == "carry":
            close = 1.0
            goal = target + (palm - ball)  # the grasp point where the ball would be at the target
        state["phase"] = phase
        state["ref"] = _rate_limit(state["ref"], goal, carry_rate if phase == "carry" else rate)
        translation, tilt = solve(q, state["ref"])

        qd = np.zeros(3) if state["prev"] is None else (q[[ARTX, ARTY, ARTZ]] - state["prev"]) / DT
        state["prev"] = q[[ARTX, ARTY, ARTZ]].copy()
        state["tilt_i"] += tilt_ki * (tilt - q[ARRX])
        ctrl = np.zeros(ACTION_DIM)
        ctrl[[ARTX, ARTY, ARTZ]] = kin.hold_ratio * (
            translation + kp * (translation - q[[ARTX, ARTY, ARTZ]]) - kd * qd
        )
        ctrl[ARTY] += kin.gravity_ctrl
        ctrl[ARRX] = kin.hold_ratio * (tilt + state["tilt_i"])
        ctrl[WRJ0] = pitch - tilt
        ctrl[WRJ1] = (kin.ctrl_low[WRJ1] + kin.ctrl_high[WRJ1]) / 2
        action = kin.normalize(ctrl)
        _hand(action, close)
        return action

    return act


def _solve_arm(
    kin: Kinematics, q: np.ndarray, target: np.ndarray, dofs: np.ndarray, pitch: float
) -> np.ndarray:
    """Damped least squares on the arm joints `dofs` (unified indices) for S_grasp = target, the wrist WRJ0
    keeping the hand pitch (ARRx + WRJ0) at `pitch`."""
    qq = q.copy()

    def grasp_site(x: np.ndarray) -> np.ndarray:
        qq[dofs] = x
        qq[WRJ0] = pitch - qq[ARRX]
        return kin.grasp_site(qq)

    x = q[dofs].copy()
    for _ in range(4):
        p = grasp_site(x)
        jac = np.zeros((3, len(dofs)))
        for i in range(len(dofs)):
            dx = x.copy()
            dx[i] += 1e-4
            jac[:, i] = (grasp_site(dx) - p) / 1e-4
        x = x + jac.T @ np.linalg.solve(jac @ jac.T + 1e-3 * np.eye(3), target - p)
        x = np.clip(x, kin.joint_low[dofs], kin.joint_high[dofs])
    return x


DOOR = TASK_BLOCKS["AdroitHandDoor-v1"][0]
REACH_TIMEOUT = 25


def door_expert(kin: Kinematics) -> Callable[[dict], np.ndarray]:
    """Press the handle down with the open palm to undo the latch (pushing the bar sideways once it points
    down), roll the hand so its palm faces the (now vertical) bar, close the fingers around it, pull the door
    along its arc, and let go at 0.8 rad while the door swings on to its stop."""
    dofs = np.array([ARTZ, ARRX, ARRY])  # the arm joints the door task has (besides the roll ARRZ)
    handle_from_axis = 0.15  # S_handle sits 0.15 m along the bar from the latch axis
    hinge_from_handle = np.array([0.31, 0.15, 0.0])  # door hinge axis relative to the closed-door handle
    press_above, press_depth, press_rate = np.array([0.0, -0.02, 0.07]), 0.25, 0.015
    side_push_at, side_push = 1.1, np.array([-0.1, -0.02, -0.03])  # push the bar past vertical
    latch_open = 1.6  # the bolt clears the post from about 1.25 rad on
    roll, roll_rate = 1.57, 0.3  # palm facing +x: the closed fingers wrap a vertical bar
    grasp_radius, retreat, grasp_offset = 0.12, np.array([0.0, -0.1, 0.0]), np.array([0.0, -0.01, 0.0])
    close_steps, ramp, reach_timeout = 12, 6, REACH_TIMEOUT
    hinge_lead, hinge_max, pull_rate = 0.3, 1.55, 0.03
    release_at, release_move = 0.8, np.array([0.1, -0.1, 0.0])
    rate, tol = 0.03, 0.035
    kp, kd, kp_rot, ki, i_max = 2.0, 0.3, 1.0, 0.1, 0.3
    thumb = np.array([0.0, 1.0, 1.0, -1.0, -1.0])
    state = {
        "phase": "above",
        "ref": None,
        "integral": np.zeros(ACTION_DIM),
        "prev": None,
        "t": 0,
        "roll": 0.0,
        "hinge_ref": 0.0,
    }

    def bar_point(handle: np.ndarray, latch: float, radius: float) -> np.ndarray:
        return handle - np.array([np.cos(latch), 0.0, -np.sin(latch)]) * (handle_from_axis - radius)

    def act(observation: dict) -> np.ndarray:
        q = np.asarray(observation["agent_pos"], dtype=np.float64)
        env_state = np.asarray(observation["environment_state"], dtype=np.float64)
        latch, hinge = float(env_state[DOOR]), float(env_state[DOOR + 1])
        handle = env_state[DOOR + 5 : DOOR + 8]
        palm = kin.grasp_site(q)
        if state["ref"] is None:
            state["ref"], state["handle0"] = palm.copy(), handle.copy()
        phase, close, roll_goal, step_rate = state["phase"], 0.0, 0.0, rate
        if phase == "above":
            goal = handle + press_above
            if np.linalg.norm(palm - goal) < tol:
                phase = "press"
        if phase == "press":
            goal, step_rate = handle + press_above - np.array([0.0, 0.0, press_depth]), press_rate
            if latch > side_push_at:
                goal = handle + side_push
            if latch > latch_open:
                phase, state["ref"] = "retreat", palm.copy()
                state["integral"][:] = 0.0
        if phase == "retreat":
            roll_goal = roll
            goal = bar_point(handle, latch, grasp_radius) + retreat
            if np.linalg.norm(palm - goal) < tol and abs(q[ARRZ] - roll) < 0.15:
                phase, state["t"] = "reach", 0
        if phase == "reach":
            roll_goal = roll
            goal = bar_point(handle, latch, grasp_radius) + grasp_offset
            state["t"] += 1
            if np.linalg.norm(palm - goal) < tol or state["t"] > reach_timeout:
                phase, state["t"] = "grasp", 0
        if phase == "grasp":
            roll_goal = roll
            state["t"] += 1
            close = min(1.0, state["t"] / ramp)
            goal = bar_point(handle, latch, grasp_radius) + grasp_offset
            if state["t"] >= close_steps:
                phase, state["grip"] = "pull", palm - handle
        if phase == "pull":
            roll_goal, close, step_rate = roll, 1.0, pull_rate
            # Keep the grip point a little ahead of the door on its arc about the hinge.
            state["hinge_ref"] = min(hinge_max, max(state["hinge_ref"], hinge + hinge_lead))
            center = state["handle0"] + hinge_from_handle
            rel = handle + state["grip"] - center
            c, s = np.cos(state["hinge_ref"] - hinge), np.sin(state["hinge_ref"] - hinge)
            goal = center + np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1], rel[2]])
            if hinge > release_at:
                phase, state["release_from"] = "release", palm.copy()
        if phase == "release":  # open the hand and step out of the swinging door's way
            roll_goal = roll
            goal = state["release_from"] + release_move
        state["phase"] = phase
        state["ref"] = _rate_limit(state["ref"], goal, step_rate)
        state["roll"] += float(np.clip(roll_goal - state["roll"], -roll_rate, roll_rate))

        q_roll = q.copy()
        q_roll[ARRZ] = state["roll"]
        x = _solve_arm(kin, q_roll, state["ref"], dofs, pitch=0.0)
        q_des = q.copy()
        q_des[dofs], q_des[ARRZ], q_des[WRJ1], q_des[WRJ0] = x, state["roll"], 0.0, -x[1]
        integral = state["integral"]
        integral[dofs] = np.clip(integral[dofs] + ki * (x - q[dofs]), -i_max, i_max)
        qd = np.zeros(ACTION_DIM) if state["prev"] is None else (q - state["prev"]) / DT
        state["prev"] = q.copy()
        ctrl = np.zeros(ACTION_DIM)
        ctrl[:6] = kin.hold_ratio * (q_des[:6] + integral[:6])
        ctrl[ARTZ] += kin.hold_ratio * (kp * (q_des[ARTZ] - q[ARTZ]) - kd * qd[ARTZ])
        ctrl[ARRX : ARRZ + 1] += kin.hold_ratio * kp_rot * (q_des[ARRX : ARRZ + 1] - q[ARRX : ARRZ + 1])
        ctrl[WRJ1 : WRJ0 + 1] = q_des[WRJ1 : WRJ0 + 1]
        action = kin.normalize(ctrl)
        _hand(action, close, thumb_closed=thumb)
        return action

    return act


PEN = TASK_BLOCKS["AdroitHandPen-v1"][0]


def pen_expert(kin: Kinematics) -> Callable[[dict], np.ndarray]:
    """A weak baseline, not a solution: fingers and thumb stay at mid-range (the pen rests in the hand) and
    the wrist tilts the hand to turn the pen's direction toward the target's (a proportional step on the
    rotation axis pen x target). Succeeds only when the target is close to the start (about one in five);
    real in-hand rotation needs finger gaiting, which this does not do."""
    gain = 0.1
    wrist = np.array(
        [(kin.ctrl_low[WRJ1] + kin.ctrl_high[WRJ1]) / 2, (kin.ctrl_low[WRJ0] + kin.ctrl_high[WRJ0]) / 2]
    )
    low, high = kin.ctrl_low[[WRJ1, WRJ0]], kin.ctrl_high[[WRJ1, WRJ0]]
    state = {"wrist": wrist.copy()}

    def act(observation: dict) -> np.ndarray:
        env_state = np.asarray(observation["environment_state"], dtype=np.float64)
        pen_dir, target_dir = env_state[PEN + 9 : PEN + 12], env_state[PEN + 12 : PEN + 15]
        axis = np.cross(pen_dir / np.linalg.norm(pen_dir), target_dir / np.linalg.norm(target_dir))
        state["wrist"] = np.clip(state["wrist"] + gain * np.array([-axis[1], axis[0]]), low, high)
        ctrl = (kin.ctrl_low + kin.ctrl_high) / 2
        ctrl[[WRJ1, WRJ0]] = state["wrist"]
        return kin.normalize(ctrl)

    return act


# Hammer has no scripted expert: its arm can only pitch and yaw (no translation), and picking the hammer up
# and striking the nail was not solved by hand; the planner (`--collector.type=planner`) does it.
EXPERTS = {
    "AdroitHandDoor-v1": door_expert,
    "AdroitHandPen-v1": pen_expert,
    "AdroitHandRelocate-v1": relocate_expert,
}


class AdroitScriptedExpert(SimulatedExpertCollector):
    name = "adroit-scripted"
    # Its phases (approach, descend, grasp, carry) and rate-limited references assume the episode's start: it
    # cannot take over a ball already knocked away or half grasped.
    acts_mid_episode = False

    def __init__(self, suite, config):
        super().__init__(suite, config)
        missing = [t for t in suite.tasks if t not in EXPERTS]
        if missing:
            raise AdaDemoError(
                f"no scripted Adroit expert for {', '.join(missing)} (scripted: {', '.join(EXPERTS)}); use "
                f"--collector.type=planner (plans with the simulator) or --collector.type=policy "
                f"--collector.path=CHECKPOINT"
            )
        self._kinematics: dict[str, Kinematics] = {}

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        if task not in self._kinematics:
            self._kinematics[task] = Kinematics(task)
        return EXPERTS[task](self._kinematics[task])
