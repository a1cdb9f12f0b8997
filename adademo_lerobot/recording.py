"""Recording is a wrapper around the env (as in Minari's DataCollector), not a special loop.

`EpisodeRecorder` turns every `step(action)` into one LeRobot frame: the observation the action was taken
in plus the action actually executed (float32, clipped), which is what makes stored actions replay exactly.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np


def frame_from_observation(observation: dict, action: np.ndarray) -> dict:
    """One LeRobot frame (without the task string) from an env observation and the action taken in it."""
    from lerobot.utils.constants import (
        ACTION,
        OBS_ENV_STATE,
        OBS_IMAGES,
        OBS_STATE,
    )  # imports torch: here, once

    frame = {  # copies: nothing that later touches the observation can change a recorded frame
        OBS_STATE: np.array(observation["agent_pos"], dtype=np.float32, copy=True),
        OBS_ENV_STATE: np.array(observation["environment_state"], dtype=np.float32, copy=True),
        ACTION: np.array(action, dtype=np.float32, copy=True),
    }
    for camera, image in observation.get("pixels", {}).items():
        frame[f"{OBS_IMAGES}.{camera}"] = np.array(image, copy=True)
    return frame


class EpisodeRecorder(gym.Wrapper):
    """Buffers (observation, executed action) frames of the current episode."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.frames: list[dict] = []
        self.succeeded = False
        self._last_obs: dict | None = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.frames = []
        self.succeeded = False
        self._last_obs = obs
        return obs, info

    def step(self, action):
        executed = np.clip(
            np.asarray(action, dtype=np.float32), self.action_space.low, self.action_space.high
        )
        self.frames.append(frame_from_observation(self._last_obs, executed))
        obs, reward, terminated, truncated, info = self.env.step(executed)
        self.succeeded |= bool(info.get("is_success", False))
        self._last_obs = obs
        return obs, reward, terminated, truncated, info
