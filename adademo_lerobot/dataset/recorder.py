"""Recording is a wrapper around the env (as in Minari's DataCollector), not a special loop.

`EpisodeRecorder` turns every `step(action)` into one LeRobot frame: the observation the action was taken
in plus the action actually executed (float32, clipped), which is what makes stored actions replay exactly.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from adademo_lerobot.core.episodes import RolloutTrace


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


class RolloutTracer(gym.Wrapper):
    """Keeps every step of the current episode: the whole state (`get_state()`) and observation before each
    action, and the action executed. A correction starts from one of these states (`adademo_lerobot.collectors.takeover`).

    Recording stops when the episode ends: a batch keeps stepping (or auto-resetting) a finished sub-env that
    holds its final observation, and those calls are not part of the episode."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.trace: RolloutTrace | None = None
        self._ended = False

    def reset(self, **kwargs):
        holding = self._ended and self.env.unwrapped.hold_after_episode
        obs, info = self.env.reset(**kwargs)
        if holding and self.env.unwrapped._holding:  # a finished sub-env repeating its final observation
            return obs, info
        self.trace = RolloutTrace([self.env.unwrapped.get_state()], [obs], [])
        self._ended = False
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if not self._ended:
            executed = np.clip(np.asarray(action, np.float32), self.action_space.low, self.action_space.high)
            self.trace.actions.append(executed)
            self.trace.states.append(self.env.unwrapped.get_state())
            self.trace.observations.append(obs)
            self._ended = terminated or truncated
        return obs, reward, terminated, truncated, info
