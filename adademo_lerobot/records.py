"""The records the layers hand each other: an expert's demonstration, a policy episode's outcome, and the
ledger's account of one task in one round. Plain dataclasses, no behaviour, no imports of the layers."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Demonstration:
    """A successful expert episode from exactly `initial_state`: LeRobot frames (observation + executed action)."""

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


@dataclass
class EpisodeRecord:
    """One policy episode from a chosen initial state."""

    task: str
    seed: int
    initial_state: list[float]
    success: bool
    steps: int
    sum_reward: float


@dataclass
class TaskRoundRecord:
    """The ledger's account of one task in one round (meta/adademo/rounds.jsonl)."""

    round: int
    task: str
    strategy: str
    target_successes: int | None
    max_demos_per_task: int | None
    demos_per_task: int | None
    policy_path: str | None
    eval_episodes: int = 0  # episodes the strategy consumed (Algorithm 1's evaluations)
    eval_episodes_run: int = (
        0  # every episode evaluated, including any run past the stopping point (real cost)
    )
    successes: int = 0
    failures: int = 0
    demos_added: int = 0
    expert_failures: int = 0
    cap_hit: bool = False
    eval_bound_hit: bool = False
    planned_demos: int | None = None  # task_only / budgeted: the demos planned for the task
    eval_env_steps: int = 0
    collection_env_steps: int = 0
    wall_seconds: float = 0.0
    expert_failed_states: list[dict] = field(default_factory=list)
    extra: dict = field(default_factory=dict)  # strategy-specific figures (e.g. the budgeted posterior)

    @property
    def success_rate(self) -> float | None:
        return self.successes / self.eval_episodes if self.eval_episodes else None
