"""The expert-collector protocol: given (task, initial state) return a demonstration or a failure.

Experts are imperfect. A collector retries from the same initial state up to `max_attempts` times (retries
add small seeded action noise, because a deterministic expert would only repeat its failure); an attempt that
does not reach success is never a demonstration, it is counted and reported.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Callable, Protocol

import draccus
import numpy as np

from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.recording import EpisodeRecorder
from adademo_lerobot.suites.base import TaskSuite, cached_for_task, derive_seed


@dataclass
class CollectorConfig(draccus.ChoiceRegistry, abc.ABC):
    max_attempts: int = 3
    # Frames kept after the first success (the episode also ends at the suite's step limit).
    post_success_frames: int = 5
    # Std of the Gaussian action noise on retries (attempt 2, 3, ...); the first attempt is the pure expert.
    retry_action_noise: float = 0.1

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    @classmethod
    def default_choice_name(cls) -> str | None:
        return "scripted"


@dataclass
class Demonstration:
    task: str
    initial_state: np.ndarray
    seed: int
    frames: list[dict]
    attempts: int


@dataclass
class CollectionResult:
    """What one collection request produced: a demonstration, or None after `attempts` failed attempts."""

    task: str
    initial_state: np.ndarray
    seed: int
    demonstration: Demonstration | None
    attempts: int
    env_steps: int
    failed_attempts: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def succeeded(self) -> bool:
        return self.demonstration is not None


class ExpertCollector(Protocol):
    name: str

    def collect(self, task: str, initial_state: np.ndarray, seed: int) -> CollectionResult:
        """A successful demonstration from exactly `initial_state`, or a counted failure."""


class PolicyExpertCollector:
    """Runs a per-task expert action function in the suite's env, recording frames through a wrapper.

    Subclasses provide `expert_for(task)`: a callable from the env observation to an action.
    """

    name = "expert"

    def __init__(self, suite: TaskSuite, config: CollectorConfig):
        if config.max_attempts < 1:
            raise AdaDemoError(f"--collector.max_attempts must be >= 1, got {config.max_attempts}")
        if config.post_success_frames < 0:
            raise AdaDemoError(f"--collector.post_success_frames must be >= 0, got {config.post_success_frames}")
        self.suite = suite
        self.config = config
        self._envs: dict[str, EpisodeRecorder] = {}

    @abc.abstractmethod
    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]: ...

    def _env(self, task: str) -> EpisodeRecorder:
        return cached_for_task(
            self._envs, task, lambda: EpisodeRecorder(self.suite.make_env(task, terminate_on_success=False)), keep=4
        )

    def collect(self, task: str, initial_state: np.ndarray, seed: int) -> CollectionResult:
        env = self._env(task)
        result = CollectionResult(task, np.asarray(initial_state, np.float64), seed, None, 0, 0)
        for attempt in range(self.config.max_attempts):
            expert = self.expert_for(task)
            noise_rng = np.random.default_rng(derive_seed(seed, "retry", attempt))
            noise = self.config.retry_action_noise if attempt > 0 else 0.0
            obs, _ = env.reset(options={"initial_state": initial_state})
            steps_after_success = None
            while True:
                action = np.asarray(expert(obs), dtype=np.float64)
                if noise > 0:
                    action = action + noise_rng.normal(0.0, noise, size=action.shape)
                obs, _, _, truncated, info = env.step(action)
                result.env_steps += 1
                if steps_after_success is not None:
                    steps_after_success += 1
                elif info["is_success"]:
                    steps_after_success = 0
                if steps_after_success is not None and steps_after_success >= self.config.post_success_frames:
                    break
                if truncated:
                    break
            result.attempts = attempt + 1
            if env.succeeded:
                result.demonstration = Demonstration(task, result.initial_state, seed, env.frames, attempt + 1)
                return result
            result.failed_attempts += 1
        return result


def make_collector(config: CollectorConfig, suite: TaskSuite) -> ExpertCollector:
    if config.type == "scripted":
        if suite.name == "metaworld":
            from adademo_lerobot.collectors.metaworld_scripted import MetaWorldScriptedExpert

            return MetaWorldScriptedExpert(suite, config)
        if suite.name == "fetch":
            from adademo_lerobot.collectors.fetch_scripted import FetchScriptedExpert

            return FetchScriptedExpert(suite, config)
        if suite.name == "adroit":
            from adademo_lerobot.collectors.adroit_scripted import AdroitScriptedExpert

            return AdroitScriptedExpert(suite, config)
        raise AdaDemoError(f"no scripted expert for suite {suite.name!r}")
    if config.type == "policy":
        from adademo_lerobot.collectors.policy import CheckpointExpert

        return CheckpointExpert(suite, config)
    raise AdaDemoError(f"unknown collector type {config.type!r}")


@CollectorConfig.register_subclass("scripted")
@dataclass
class ScriptedCollectorConfig(CollectorConfig):
    """The suite's built-in scripted experts (MetaWorld: `metaworld.policies`; Fetch: `fetch_scripted`; Adroit:
    `adroit_scripted`)."""
