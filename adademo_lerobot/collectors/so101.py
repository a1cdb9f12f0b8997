"""The scripted pick-and-place controller of `lerobot-env-so101` as an expert for its `SO101PickPlace-v0` task:

    --collector.type=callable --collector.entry=adademo_lerobot.collectors.so101:pick_place

The package's `PickPlaceController.act(grasp_pos, block_pos, goal_pos)` reads the block and the goal from the
observation (`environment_state` = block xyz, goal xyz) and the point the action moves from the env
(`ik_point_pos`, which the observation does not hold), and the env's metres per unit action.
"""

from __future__ import annotations

import numpy as np


def pick_place(env):
    """A fresh controller (its phase starts over) for one attempt on `env` (the package's own env)."""
    from lerobot_env_so101.scripted.pick_place import PickPlaceController

    raw = env.unwrapped
    controller = PickPlaceController(action_scale=raw._action_scale)  # the env's metres per unit action

    def act(observation: dict) -> np.ndarray:
        state = np.asarray(observation["environment_state"], np.float64)
        return controller.act(raw.ik_point_pos, state[:3], state[3:6])

    return act
