"""Adroit's dense rewards computed from a MuJoCo state, for the planner's batched rollouts.

`shaped=False` is each v1 env's own `step` reward, term for term (the tests check it against the env's).
`shaped=True` is what the planner scores by default: the same terms with the changes below, each measured on
seeded initial states (benchmarks/results/adroit_expert_success.md):

- every task: the palm-to-object term has DAPG's sign (-0.1 x distance). gymnasium-robotics' v1 envs add
  +0.1 x distance, so they pay the hand for moving *away* from the handle, hammer or ball.
- pen: the pen's distance from its place in the palm weighs 20 (the env: 1). With 1, the planner turns the pen
  toward the target by flicking it out of the hand, and it drops.
- hammer: the palm-to-hammer distance weighs 3, and the lift bonus counts only while the palm is within 6 cm of
  the hammer. Otherwise the planner earns the bonus by knocking the hammer into the air.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

PEN_DISTANCE_WEIGHT = 20.0
HAMMER_PALM_WEIGHT = 3.0
HAMMER_GRIP_DISTANCE = 0.06


def _norm(vector: np.ndarray) -> float:
    return float(np.linalg.norm(vector))


def door_reward(env, data: mujoco.MjData, shaped: bool) -> float:
    hinge = float(data.qpos[env.door_hinge_addrs])
    reach = _norm(data.site_xpos[env.grasp_site_id] - data.site_xpos[env.handle_site_id])
    reward = (-0.1 if shaped else 0.1) * reach
    reward += -0.1 * (hinge - 1.57) * (hinge - 1.57) - 1e-5 * float(np.sum(data.qvel**2))
    return reward + 2 * (hinge > 0.2) + 8 * (hinge > 1.0) + 10 * (hinge > 1.35)


def hammer_reward(env, data: mujoco.MjData, shaped: bool) -> float:
    hammer, palm = data.xpos[env.obj_body_id], data.site_xpos[env.S_grasp_site_id]
    head, nail = data.site_xpos[env.tool_site_id], data.site_xpos[env.target_obj_site_id]
    goal_distance = _norm(nail - data.site_xpos[env.goal_site_id])
    grip = _norm(palm - hammer)
    reward = (-HAMMER_PALM_WEIGHT if shaped else 0.1) * grip
    reward -= _norm(head - nail) + 10 * goal_distance + 1e-2 * _norm(data.qvel)
    lifted = hammer[2] > 0.04 and head[2] > 0.04 and (grip < HAMMER_GRIP_DISTANCE or not shaped)
    return reward + 2 * lifted + 25 * (goal_distance < 0.020) + 75 * (goal_distance < 0.010)


def pen_reward(env, data: mujoco.MjData, shaped: bool) -> float:
    pen = data.xpos[env.obj_body_id]
    distance = _norm(pen - data.site_xpos[env.eps_ball_site_id])
    pen_direction = (data.site_xpos[env.obj_t_site_id] - data.site_xpos[env.obj_b_site_id]) / env.pen_length
    target = (data.site_xpos[env.tar_t_site_id] - data.site_xpos[env.tar_b_site_id]) / env.tar_length
    similarity = float(np.dot(pen_direction, target))
    reward = -(PEN_DISTANCE_WEIGHT if shaped else 1.0) * distance + similarity
    reward += 10 * (distance < 0.075 and similarity > 0.9) + 50 * (distance < 0.075 and similarity > 0.95)
    return reward - 5 * (pen[2] < 0.075)


def relocate_reward(env, data: mujoco.MjData, shaped: bool) -> float:
    ball, palm = data.xpos[env.obj_body_id], data.site_xpos[env.S_grasp_site_id]
    target = data.site_xpos[env.target_obj_site_id]
    goal_distance = _norm(ball - target)
    reward = (-0.1 if shaped else 0.1) * _norm(palm - ball)
    if ball[2] > 0.04:  # off the table
        reward += 1.0 - 0.5 * _norm(palm - target) - 0.5 * goal_distance
    return reward + 10.0 * (goal_distance < 0.1) + 20.0 * (goal_distance < 0.05)


REWARDS = {
    "AdroitHandDoor-v1": door_reward,
    "AdroitHandHammer-v1": hammer_reward,
    "AdroitHandPen-v1": pen_reward,
    "AdroitHandRelocate-v1": relocate_reward,
}


def reward_function(task: str, raw_env, shaped: bool) -> Callable[[mujoco.MjData], float]:
    """`task`'s reward of a state (`MjData` with positions computed) of `raw_env`'s model."""
    reward = REWARDS[task]
    return lambda data: reward(raw_env, data, shaped)
