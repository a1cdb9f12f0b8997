"""Scripted experts for the Fetch suite: small state machines over the suite's 25-D observation + goal.

Actions are Cartesian gripper displacements (times 0.05 m in the env; the gripper actually moves about
0.03 m per step at full action) and a finger command (+1 open, -1 close; ignored where the gripper is blocked).
Each call of `expert_for` returns a fresh controller (its phase starts over), so every attempt is the same
deterministic function of the initial state.

- Reach: proportional control of the gripper to the goal.
- Push: go up, move behind the block on the line goal -> block, lower to block height, push along the line
  while correcting sideways; back off and realign when the block slips off the line.
- PickAndPlace: above the block with open fingers, descend, close, lift, carry the block to the goal.
- Slide: line up behind the puck on the line goal -> puck, one full-speed strike toward the goal, then stand
  still while the puck slides on the low-friction table (about 80% success; the arm's reach and speed limit
  the distance a puck can be sent).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from adademo_lerobot.collectors.base import SimulatedExpertCollector
from adademo_lerobot.suites.fetch import GOAL_DIM, OBS_DIM

STEP = 0.05  # metres of mocap displacement per unit action (the env's own scale)


def _parse(observation: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grip xyz, object xyz, goal xyz) from an env observation (object xyz is zero for Reach)."""
    state = np.asarray(observation["environment_state"], dtype=np.float64)
    obs, goal = state[:OBS_DIM], state[OBS_DIM : OBS_DIM + GOAL_DIM]
    return obs[0:3].copy(), obs[3:6].copy(), goal.copy()


def _move(target: np.ndarray, current: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """Displacement action toward `target` (one full step covers the error when gain is 1)."""
    return np.clip(gain * (target - current) / STEP, -1.0, 1.0)


def _action(move: np.ndarray, fingers: float) -> np.ndarray:
    return np.concatenate([np.clip(move, -1.0, 1.0), [fingers]]).astype(np.float64)


def reach_expert() -> Callable[[dict], np.ndarray]:
    def act(observation: dict) -> np.ndarray:
        grip, _, goal = _parse(observation)
        return _action(_move(goal, grip, gain=1.5), 0.0)

    return act


def push_expert() -> Callable[[dict], np.ndarray]:
    behind = 0.06  # gripper centre behind the block centre while lining up (block half-size 0.025 m)
    contact = 0.045  # ... and while pushing
    clearance = 0.06  # height above the block while moving around it
    phase = ["approach"]

    def act(observation: dict) -> np.ndarray:
        grip, obj, goal = _parse(observation)
        to_goal = goal[:2] - obj[:2]
        dist = float(np.linalg.norm(to_goal))
        u = to_goal / dist if dist > 1e-6 else np.array([1.0, 0.0])
        rel = grip[:2] - obj[:2]
        along, across = float(rel @ u), float(rel @ np.array([-u[1], u[0]]))
        if phase[0] == "push" and (along > -0.02 or abs(across) > 0.03):
            phase[0] = "approach"  # the block slipped off the line or the gripper passed it: realign
        if phase[0] == "approach":
            spot = obj[:2] - u * behind
            high = obj[2] + clearance
            if grip[2] < high - 0.02 and np.linalg.norm(grip[:2] - spot) > 0.02:
                # Low and not yet behind the block: rise first (only move sideways once above the block).
                move = _move(np.array([grip[0], grip[1], high]), grip)
                if grip[2] > obj[2] + 0.035:
                    move[:2] = _move(spot, grip[:2])
                return _action(move, -1.0)
            if np.linalg.norm(grip[:2] - spot) > 0.015:
                return _action(_move(np.array([*spot, high]), grip), -1.0)
            phase[0] = "lower"
        if phase[0] == "lower":
            spot = obj[:2] - u * behind
            target = np.array([*spot, obj[2]])
            if abs(grip[2] - obj[2]) > 0.01:
                return _action(_move(target, grip), -1.0)
            phase[0] = "push"
        # Push: stay on the line behind the block, advance along it, slow down near the goal.
        line = obj[:2] - u * contact
        speed = min(1.0, 0.4 + 8.0 * dist)
        move_xy = _move(line, grip[:2]) + u * speed
        move_z = _move(np.array([obj[2]]), grip[2:3])
        return _action(np.concatenate([move_xy, move_z]), -1.0)

    return act


def pick_and_place_expert() -> Callable[[dict], np.ndarray]:
    phase = ["above"]
    closing_steps = [0]

    def act(observation: dict) -> np.ndarray:
        grip, obj, goal = _parse(observation)
        if phase[0] == "above":
            target = np.array([obj[0], obj[1], obj[2] + 0.04])
            if np.linalg.norm(grip[:2] - obj[:2]) > 0.01:
                move = _move(target, grip)
                return _action(move, 1.0)
            phase[0] = "descend"
        if phase[0] == "descend":
            if grip[2] - obj[2] > 0.008 or np.linalg.norm(grip[:2] - obj[:2]) > 0.01:
                return _action(_move(obj, grip, gain=1.5), 1.0)
            phase[0] = "close"
        if phase[0] == "close":
            closing_steps[0] += 1
            if closing_steps[0] <= 3:
                return _action(_move(obj, grip), -1.0)
            phase[0] = "carry"
        # Carry: lift off the table first, then bring the block (not the gripper) to the goal.
        if np.linalg.norm(obj - grip) > 0.05:  # dropped: start over
            phase[0], closing_steps[0] = "above", 0
            return _action(np.zeros(3), 1.0)
        target = goal + (grip - obj)
        if obj[2] < goal[2] + 0.01 and np.linalg.norm(goal[:2] - obj[:2]) > 0.03:
            target[2] = max(target[2], grip[2] + 0.03)  # lift while travelling
        return _action(_move(target, grip, gain=1.5), -1.0)

    return act


def slide_expert() -> Callable[[dict], np.ndarray]:
    """Line up behind the puck, then strike toward the goal at full speed for a few steps and stand still.

    The gripper cannot follow the puck far (the arm's reach ends near x = 1.40 m), so the puck must be hit:
    at full speed it slides about 0.6 m, which reaches most goals (passing over the goal counts as success).
    Measured alternatives that did worse: a speed profile falling with sqrt(distance) (the puck drifts off
    the line while being pushed), hitting with the pusher's corner, a longer run-up.
    """
    behind = 0.06  # gripper centre behind the puck centre (puck radius 0.025 m, finger half-width 0.0135 m)
    phase = ["approach"]
    strike = {"done": 0, "planned": 0, "direction": None}

    def act(observation: dict) -> np.ndarray:
        grip, obj, goal = _parse(observation)
        to_goal = goal[:2] - obj[:2]
        dist = float(np.linalg.norm(to_goal))
        u = to_goal / dist if dist > 1e-6 else np.array([1.0, 0.0])
        spot = obj[:2] - u * behind
        if phase[0] == "approach":
            high = obj[2] + 0.06
            if np.linalg.norm(grip[:2] - spot) > 0.01:
                move = _move(np.array([*spot, high]), grip)
                if grip[2] < obj[2] + 0.035 and np.linalg.norm(grip[:2] - spot) > 0.04:
                    move[:2] = 0.0  # low and not behind the puck: rise first
                return _action(move, -1.0)
            phase[0] = "lower"
        if phase[0] == "lower":
            if abs(grip[2] - obj[2]) > 0.008 or np.linalg.norm(grip[:2] - spot) > 0.01:
                return _action(_move(np.array([*spot, obj[2]]), grip), -1.0)
            phase[0] = "strike"
            strike["planned"] = int(np.clip(round(SLIDE_STRIKE_STEPS_PER_METRE * dist), 1, 12))
            strike["direction"] = u  # fixed for the whole strike
        if phase[0] == "strike" and strike["done"] < strike["planned"]:
            strike["done"] += 1
            move_z = _move(np.array([obj[2]]), grip[2:3])
            return _action(np.concatenate([strike["direction"], move_z]), -1.0)
        phase[0] = "wait"
        return _action(np.zeros(3), -1.0)

    return act


SLIDE_STRIKE_STEPS_PER_METRE = 10.0

EXPERTS = {
    "FetchReach-v4": reach_expert,
    "FetchPush-v4": push_expert,
    "FetchPickAndPlace-v4": pick_and_place_expert,
    "FetchSlide-v4": slide_expert,
}


class FetchScriptedExpert(SimulatedExpertCollector):
    name = "fetch-scripted"

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        return EXPERTS[task]()
