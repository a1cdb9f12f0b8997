import numpy as np

from lerobot_env_example.env import SPEED


def reach(env):
    """--collector.type=callable --collector.entry=lerobot_env_example.expert:reach: a controller for one attempt."""

    def act(observation: dict) -> np.ndarray:
        return np.clip((observation["environment_state"] - observation["agent_pos"]) / SPEED, -1.0, 1.0)

    return act
