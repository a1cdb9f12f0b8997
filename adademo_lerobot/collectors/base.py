"""The expert-collector protocol: given (task, initial state) return a demonstration or a counted failure.

Experts are imperfect. A collector retries from the same initial state up to `max_attempts` times (retries
add small seeded action noise, because a deterministic expert would only repeat its failure); an attempt that
does not reach success is never a demonstration, it is counted and reported.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import draccus
import numpy as np

from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.episodes import CollectionResult, Demonstration
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import retry_noise_seed
from adademo_lerobot.dataset.recorder import EpisodeRecorder
from adademo_lerobot.suites.base import TaskSuite, cached_for_task, full_state_step


@dataclass
class CollectorConfig(draccus.ChoiceRegistry, abc.ABC):
    """Which expert records the demonstrations (`--collector.type=scripted|policy|callable|planner`); each config
    builds its own collector for a suite."""

    max_attempts: int = 3
    # Frames kept after the first success (the episode also ends at the suite's step limit).
    post_success_frames: int = 5
    # Std of the Gaussian action noise on retries (attempt 2, 3, ...); the first attempt is the pure expert.
    retry_action_noise: float = 0.1
    # Fields that set how fast the expert runs, not what it does: left out of `to_dict`, free to change on resume.
    execution_fields: ClassVar[tuple[str, ...]] = ()

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    def to_dict(self) -> dict[str, Any]:
        """The expert as a round's journal and ledger and `run_state.json` keep it (its provenance; a resumed round
        or run must keep it): the type and every field but the execution fields."""
        values = dataclasses.asdict(self)
        return {"type": self.type, **{k: v for k, v in values.items() if k not in self.execution_fields}}

    @classmethod
    def default_choice_name(cls) -> str | None:
        return "scripted"

    @classmethod
    def serves(cls, suite: TaskSuite) -> bool:
        """Whether this type of expert can act in `suite` at all (an error that names other experts names these)."""
        return True

    @abc.abstractmethod
    def build(self, suite: TaskSuite) -> ExpertCollector:
        """The collector this config describes, for `suite`."""

    def validate(self, suite: TaskSuite) -> None:
        """Refuse a bad expert (unknown for the suite, a missing or mismatched checkpoint) before anything is
        written: builds it once (cheap: simulators and policies load on first use)."""
        collector = self.build(suite)
        if hasattr(collector, "close"):
            collector.close()

    @abc.abstractmethod
    def expert_name(self, suite: TaskSuite) -> str:
        """The name recorded in each episode's `adademo/collector` (without building the expert)."""

    def check_acts_mid_episode(self, suite: TaskSuite) -> None:
        """Refuse `--demo_start=takeover` with an expert that cannot take over an episode mid-way."""
        if not self.expert_class(suite).acts_mid_episode:
            raise AdaDemoError(
                f"--demo_start=takeover: the {self.expert_name(suite)} expert cannot take over mid-episode (it "
                "acts only from an episode's start); use --demo_start=initial, or an expert that acts from any "
                "state (--collector.type=policy)"
            )

    @abc.abstractmethod
    def expert_class(self, suite: TaskSuite) -> type:
        """The collector class `build` makes (read without building it)."""


def expert_summary(settings: dict) -> str:
    """`type (field=value, ...)` of a journaled expert (`CollectorConfig.to_dict`), naming the fields that differ
    from its type's defaults (all of them for a type without a config here: a person's)."""
    kind = settings.get("type", "?")
    known = CollectorConfig.get_known_choices()
    defaults = CollectorConfig.get_choice_class(kind)().to_dict() if kind in known else {}
    parts = []
    for key, value in settings.items():
        if key == "type" or (key in defaults and value == defaults[key]):
            continue
        if isinstance(value, dict):  # per-task settings: only the fields each task sets
            value = {
                task: {f: x for f, x in fields.items() if x is not None} for task, fields in value.items()
            }
        parts.append(f"{key}={value}")
    return f"{kind} ({', '.join(parts)})" if parts else kind


class ExpertCollector(Protocol):
    name: str
    # Whether the expert can take over mid-episode, from any state (`--demo_start=takeover`).
    acts_mid_episode: bool

    def collect(
        self, task: str, initial_state: np.ndarray, seed: int, start_state: np.ndarray | None = None
    ) -> CollectionResult:
        """A successful demonstration from exactly `initial_state` (or, for a correction, from `start_state`, a
        state of an episode from `initial_state`), or a counted failure."""


class SimulatedExpertCollector:
    """Runs an expert's per-step action function in the suite's simulator, recording frames through a wrapper.

    The base of every simulated expert (the scripted ones and a policy checkpoint used as the expert).
    Subclasses provide `expert_for(task)`: a callable from the env observation to an action.
    """

    name = "expert"
    acts_mid_episode = True  # a fresh expert acts from the observation it is given, whatever the step

    def __init__(self, suite: TaskSuite, config: CollectorConfig):
        if config.max_attempts < 1:
            raise AdaDemoError(f"--collector.max_attempts must be >= 1, got {config.max_attempts}")
        if config.post_success_frames < 0:
            raise AdaDemoError(
                f"--collector.post_success_frames must be >= 0, got {config.post_success_frames}"
            )
        self.suite = suite
        self.config = config
        self._envs: dict[str, EpisodeRecorder] = {}

    @abc.abstractmethod
    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]: ...

    def expert_first_action(self, task: str) -> Callable[[dict, np.ndarray], np.ndarray]:
        """The action a fresh expert would take first at an observation and whole state (what it does when it
        takes over there); an expert that acts from observations reads the observation only."""
        return lambda observation, state: np.asarray(self.expert_for(task)(observation), np.float64)

    def _env(self, task: str) -> EpisodeRecorder:
        return cached_for_task(
            self._envs,
            task,
            lambda: EpisodeRecorder(self.suite.make_env(task, terminate_on_success=False)),
            keep=4,
        )

    def collect(
        self,
        task: str,
        initial_state: np.ndarray,
        seed: int,
        start_state: np.ndarray | None = None,
        takeover: TakeoverArgs | None = None,
    ) -> CollectionResult:
        """A demonstration from `initial_state`; for a correction, from `start_state` (`takeover.attempts`
        attempts) and, if the expert fails there, from `initial_state` (`takeover.fallback`)."""
        env = self._env(task)
        result = CollectionResult(task, np.asarray(initial_state, np.float64), seed, None, 0, 0)
        if start_state is not None:
            takeover = takeover or TakeoverArgs()
            result.start_step = full_state_step(start_state)
            # A correction is an episode of its own: the expert gets the whole step limit from the takeover state.
            start = {"state": start_state, "new_episode": True}
            if self._attempts(env, task, result, start, takeover.attempts, np.asarray(start_state)):
                return result
            result.takeover_failed = True
            if takeover.fallback == "none":
                return result
            result.start_step = 0
        self._attempts(env, task, result, {"initial_state": initial_state}, self.config.max_attempts, None)
        return result

    def _attempts(
        self, env, task: str, result: CollectionResult, start: dict, n: int, correction_from
    ) -> bool:
        """Up to n attempts from `start` (the first the pure expert, then with seeded noise); True with a
        demonstration in `result`."""
        seed = result.seed
        for attempt in range(n):
            expert = self.expert_for(task)
            noise_rng = np.random.default_rng(retry_noise_seed(seed, attempt))
            noise = self.config.retry_action_noise if attempt > 0 else 0.0
            obs, _ = env.reset(options=start)
            if correction_from is not None:
                start_vector = correction_from
            elif self.suite.restores_any_state:
                start_vector = env.unwrapped.get_state()  # the whole state at the episode's start
            else:  # a suite that restores initial states only: that is the whole start it knows
                start_vector = result.initial_state
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
            result.attempts += 1
            if env.succeeded:
                result.demonstration = Demonstration(
                    task,
                    result.initial_state,
                    seed,
                    env.frames,
                    result.attempts,
                    result.start_step,
                    np.asarray(start_vector, np.float64),
                    is_correction=correction_from is not None,
                )
                return True
            result.failed_attempts += 1
        return False

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()
