"""Recording is a wrapper around the env (as in Minari's DataCollector), not a special loop.

`EpisodeRecorder` turns every `step(action)` into one LeRobot frame: the observation the action was taken
in plus the action actually executed (float32, clipped), which is what makes stored actions replay exactly.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from adademo_lerobot.core.episodes import Demonstration, RolloutTrace, executed_action


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
        executed = executed_action(action, self.action_space.low, self.action_space.high)
        self.frames.append(frame_from_observation(self._last_obs, executed))
        obs, reward, terminated, truncated, info = self.env.step(executed)
        self.succeeded |= bool(info.get("is_success", False))
        self._last_obs = obs
        return obs, reward, terminated, truncated, info


class RolloutTracer(gym.Wrapper):
    """Keeps every step of the current episode: the whole state (`get_state()`, unless `with_states` is False) and
    observation before each action, and the action executed. A correction starts from one of these states
    (`adademo_lerobot.collectors.takeover`); a kept success is its observations and actions
    (`demonstration_from_trace`).

    Recording stops when the episode ends: a batch keeps stepping (or auto-resetting) a finished sub-env that
    holds its final observation, and those calls are not part of the episode."""

    def __init__(self, env: gym.Env, with_states: bool = True):
        super().__init__(env)
        self.trace: RolloutTrace | None = None
        self.with_states = with_states
        self._ended = False

    def _state(self) -> np.ndarray | None:
        return self.env.unwrapped.get_state() if self.with_states else None

    def reset(self, **kwargs):
        holding = self._ended and self.env.unwrapped.hold_after_episode
        obs, info = self.env.reset(**kwargs)
        if holding and self.env.unwrapped._holding:  # a finished sub-env repeating its final observation
            return obs, info
        self.trace = RolloutTrace([self._state()], [obs], [])
        self._ended = False
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if not self._ended:
            executed = executed_action(action, self.action_space.low, self.action_space.high)
            self.trace.actions.append(executed)
            self.trace.states.append(self._state())
            self.trace.observations.append(obs)
            self._ended = terminated or truncated
        return obs, reward, terminated, truncated, info


def demonstration_from_trace(task: str, seed: int, initial_state, trace: RolloutTrace) -> Demonstration:
    """A successful policy rollout as data (`--keep_successes`): its frames as the expert's are recorded (the
    observation each action was taken in and the action executed), from the initial state (and the whole state
    there, where the trace has states: what it replays from), marked `by_policy`."""
    frames = [frame_from_observation(o, a) for o, a in zip(trace.observations, trace.actions, strict=False)]
    state, start = np.asarray(initial_state, np.float64), trace.states[0]
    return Demonstration(task, state, int(seed), frames, attempts=1, start_state=start, by_policy=True)
