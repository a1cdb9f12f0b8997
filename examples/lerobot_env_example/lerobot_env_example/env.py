import gymnasium as gym
import numpy as np

SPEED = 0.1  # distance moved per step at full action


class PointReachEnv(gym.Env):
    """A point that must come within `tolerance` of a goal; both are placed from the reset seed alone."""

    def __init__(self, tolerance: float = 0.05):
        if tolerance <= 0:
            raise ValueError(f"tolerance must be > 0, got {tolerance}")
        self.tolerance = tolerance
        plane = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)
        self.observation_space = gym.spaces.Dict({"agent_pos": plane, "environment_state": plane})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)  # a velocity

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)  # seeds self.np_random: the same seed gives the same layout
        self.point = self.np_random.uniform(-0.5, 0.5, 2)
        self.goal = self.np_random.uniform(-0.5, 0.5, 2)
        return self._observation(), {"is_success": False}

    def step(self, action):
        self.point = np.clip(self.point + SPEED * np.asarray(action, np.float64), -1.0, 1.0)
        success = bool(np.linalg.norm(self.goal - self.point) < self.tolerance)
        return self._observation(), float(success), False, False, {"is_success": success}

    def _observation(self) -> dict:
        return {"agent_pos": self.point.copy(), "environment_state": self.goal.copy()}
