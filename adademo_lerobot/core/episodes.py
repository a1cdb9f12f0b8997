"""The records the layers hand each other: an expert's demonstration, a policy episode's outcome, and the
ledger's account of one task in one round. Plain dataclasses, no behaviour (but how a demonstration pickles its
frames), no imports of the layers."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


def executed_action(action, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The action a step executes and a dataset stores: float32, clipped to the action space. `np.clip`'s result,
    without its per-call overhead (~2 us, which every recorded step paid twice)."""
    return np.minimum(np.maximum(np.asarray(action, dtype=np.float32), low), high)


@dataclass
class Demonstration:
    """A successful expert episode: LeRobot frames (observation + executed action) from exactly `start_state`,
    the whole state it started from: `initial_state`'s at step 0, or, for a correction, the state at step
    `start_step` of a failed policy rollout from `initial_state` (on a robot: its joint positions then)."""

    task: str
    initial_state: np.ndarray
    seed: int
    frames: list[dict]
    attempts: int
    start_step: int = 0
    start_state: np.ndarray | None = None  # None: the initial state is all there is (a robot's joints)
    is_correction: bool = False
    # A successful policy rollout kept as data (--keep_successes: `adademo/source=policy`), not an expert's.
    by_policy: bool = False

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    # Pickled (a Ray worker's result, --ray.worker_writes=false) as one array per key rather than a few small
    # arrays per frame: Ray sends each array as its own buffer, ~200 for a 66-frame MetaWorld episode.
    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        if self.frames and all(frame.keys() == self.frames[0].keys() for frame in self.frames):
            state["frames"] = {key: _column([frame[key] for frame in self.frames]) for key in self.frames[0]}
        return state

    def __setstate__(self, state: dict) -> None:
        if isinstance(state["frames"], dict):
            columns = state["frames"]
            count = len(next(iter(columns.values())))
            state["frames"] = [{key: column[i] for key, column in columns.items()} for i in range(count)]
        self.__dict__.update(state)


def _column(values: list):
    """The values of one key across frames: stacked if they are arrays of one shape and dtype (a row of the stack
    is then equal to the frame's own array), else the list itself."""
    first = values[0]
    if (
        isinstance(first, np.ndarray)
        and first.ndim
        and all(
            isinstance(v, np.ndarray) and v.shape == first.shape and v.dtype == first.dtype for v in values
        )
    ):
        return np.stack(values)
    return values


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
    start_step: int = 0  # a correction's step within the failed rollout (0: from the initial state)
    # The expert failed from the takeover state (any demonstration is a fallback).
    takeover_failed: bool = False


@dataclass
class EpisodeRecord:
    """One policy episode from a chosen initial state."""

    task: str
    seed: int
    initial_state: list[float]
    success: bool
    steps: int
    sum_reward: float
    # --demo_start=takeover, failed episodes: where the expert takes over (step, rule, whole state there).
    takeover_step: int | None = None
    takeover_rule: str | None = None
    takeover_state: list[float] | None = None
    # --keep_successes, successful episodes: the rollout as a Demonstration (`by_policy`), or the shard a Ray
    # worker wrote it to. Not a figure: tables of records leave it out (`record_row`).
    kept: object = None


def record_row(record: EpisodeRecord) -> dict:
    """An episode record's figures, as tables of evaluations store them."""
    return {f.name: getattr(record, f.name) for f in fields(record) if f.name != "kept"}


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
    # Every policy episode the round ran (the rollouts of the cost model, `costs.py`); the same as `eval_episodes`,
    # since evaluations never run past the stopping point.
    eval_episodes_run: int = 0
    successes: int = 0
    failures: int = 0
    demos_added: int = 0
    expert_failures: int = 0
    cap_hit: bool = False
    eval_bound_hit: bool = False
    planned_demos: int | None = None  # task_only / budgeted: the demos planned for the task
    eval_env_steps: int = 0
    collection_env_steps: int = 0  # env steps under the expert's control, failed attempts included
    demo_frames: int = 0  # frames of the demonstrations added (a correction's: from its takeover step)
    corrections: int = 0  # demonstrations that start mid-episode (--demo_start=takeover)
    policy_episodes_kept: int = 0  # --keep_successes: successful rollouts added as `adademo/source=policy`
    # Takeover states the expert failed from (answered from the initial state, or not).
    takeover_failures: int = 0
    wall_seconds: float = 0.0
    expert_failed_states: list[dict] = field(default_factory=list)
    # The expert, as its config's `to_dict` (a person's rounds: the teleoperator and robot); {} in rounds
    # written before it was recorded.
    collector: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)  # strategy-specific figures (e.g. the budgeted posterior)

    @property
    def success_rate(self) -> float | None:
        return self.successes / self.eval_episodes if self.eval_episodes else None


@dataclass
class RolloutTrace:
    """A policy episode step by step: the whole state (`get_state()`) and the observation before every action
    (one more than actions: the last is where the episode ended) and the action executed."""

    states: list[np.ndarray]
    observations: list[dict]
    actions: list[np.ndarray]
