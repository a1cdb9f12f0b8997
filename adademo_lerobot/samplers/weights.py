"""How much each episode is sampled during training.

A scheme gives every episode a probability; frames inside an episode are uniform over the frames the policy
can train on. The per-frame weights are computed once and drawn from with replacement.

- `frame`: uniform over frames (LeRobot's default) - long episodes, and tasks with long episodes, weigh more.
- `task`: every task equally likely, then uniform over its trajectories.
- `trajectory` (AdaDemo, principle C): every trajectory equally likely, so task k's share is n_k / sum(n);
  tasks below `min_task_weight` are lifted to it and the rest share the remainder in proportion to n_k.
- `tempered`: task k's share proportional to n_k ** alpha (`--sampler_alpha`; 1 = `trajectory`, 0 = `task`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import pandas as pd

from adademo_lerobot.core.errors import AdaDemoError


def floor_shares(shares: dict[str, float], floor: float) -> dict[str, float]:
    """Raise every share below `floor` to it and renormalize the others so each final share is >= floor.

    Water-filling: tasks pinned at the floor stay there, the rest keep their relative proportions.
    """
    if floor <= 0:
        return dict(shares)
    if floor * len(shares) > 1 + 1e-12:
        raise AdaDemoError(f"min_task_weight={floor} is above 1/num_tasks={1 / len(shares):.4f}")
    pinned: set[str] = set()
    while True:
        free = {k: v for k, v in shares.items() if k not in pinned}
        remaining = 1.0 - floor * len(pinned)
        total = sum(free.values())
        scaled = {k: remaining * v / total for k, v in free.items()} if total > 0 else {}
        newly = {k for k, v in scaled.items() if v < floor}
        if not newly:
            return {**dict.fromkeys(pinned, floor), **scaled}
        pinned |= newly


class SamplingScheme(Protocol):
    name: str

    def episode_probabilities(
        self, episode_tasks: pd.Series, episode_lengths: pd.Series, weights: np.ndarray | None = None
    ) -> np.ndarray:
        """Probability of drawing each episode (sums to 1), in the order of `episode_tasks`. An episode of
        weight w counts as w episodes (the policy's own, `--autonomous_weight`): in its task's trajectories
        and in its draws."""


def _weights(weights: np.ndarray | None, n: int) -> np.ndarray:
    return np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)


class FrameUniform:
    name = "frame"

    def episode_probabilities(self, episode_tasks, episode_lengths, weights=None) -> np.ndarray:
        lengths = np.asarray(episode_lengths, dtype=np.float64) * _weights(weights, len(episode_lengths))
        return lengths / lengths.sum()


class Tempered:
    """Task k's share proportional to n_k ** alpha (n_k: its trajectories), then uniform over its trajectories.

    alpha = 1 is AdaDemo's principle C (trajectory-uniform: a task's share is n_k / sum n), alpha = 0 is
    task-uniform; in between, tasks that got more demos get more weight, less than in proportion. Tasks below
    `min_task_weight` are lifted to it and the rest keep their proportions."""

    name = "tempered"

    def __init__(self, alpha: float = 1.0, min_task_weight: float = 0.0):
        self.alpha, self.min_task_weight = alpha, min_task_weight

    def task_shares(self, episode_tasks, weights: np.ndarray | None = None) -> dict[str, float]:
        counts = _task_counts(episode_tasks, weights)
        powered = {t: float(c) ** self.alpha for t, c in counts.items()}
        total = sum(powered.values())
        return floor_shares({t: v / total for t, v in powered.items()}, self.min_task_weight)

    def episode_probabilities(self, episode_tasks, episode_lengths, weights=None) -> np.ndarray:
        tasks = np.asarray(episode_tasks)
        counts, shares = _task_counts(tasks, weights), self.task_shares(tasks, weights)
        w = _weights(weights, len(tasks))
        return np.array([shares[t] * wi / counts[t] for t, wi in zip(tasks, w, strict=True)])


def _task_counts(episode_tasks, weights: np.ndarray | None) -> pd.Series:
    """Each task's trajectories, an episode of weight w counting as w (unweighted: counted exactly as before
    weights existed, in the same order, so the shares' float sums and a run's draws stay the same)."""
    tasks = np.asarray(episode_tasks)
    if weights is None:
        return pd.Series(tasks).value_counts()
    return pd.Series(np.asarray(weights, dtype=np.float64)).groupby(tasks).sum()


class TrajectoryUniform(Tempered):
    """AdaDemo's principle C: every trajectory equally likely (`tempered` with alpha = 1)."""

    name = "trajectory"

    def __init__(self, min_task_weight: float = 0.0):
        super().__init__(1.0, min_task_weight)


class TaskUniform(Tempered):
    """Every task equally likely, then uniform over its trajectories (`tempered` with alpha = 0)."""

    name = "task"

    def __init__(self):
        super().__init__(0.0, 0.0)


SAMPLERS = ("trajectory", "task", "frame", "tempered")


def check_sampler_flags(name: str, alpha: float) -> None:
    if name not in SAMPLERS:
        raise AdaDemoError(f"unknown --sampler={name!r}; choose one of {', '.join(SAMPLERS)}")
    if alpha < 0:
        raise AdaDemoError(
            f"--sampler_alpha must be >= 0 (0: task-uniform, 1: trajectory-uniform), got {alpha}"
        )


def make_sampling_scheme(
    name: str, min_task_weight: float, num_tasks: int, alpha: float = 1.0
) -> SamplingScheme:
    check_sampler_flags(name, alpha)
    if not 0.0 <= min_task_weight <= 1.0 / max(num_tasks, 1) + 1e-12:
        raise AdaDemoError(
            f"--min_task_weight={min_task_weight} must be in [0, 1/num_tasks] = [0, {1 / max(num_tasks, 1):.4f}]"
        )
    if name == "frame":
        return FrameUniform()
    if name == "task":
        return TaskUniform()
    if name == "tempered":
        return Tempered(alpha, min_task_weight)
    return TrajectoryUniform(min_task_weight)


def frame_weights(
    scheme: SamplingScheme, episodes: pd.DataFrame, num_frames: int, drop_n_last_frames: int = 0
) -> np.ndarray:
    """Per-frame probabilities over the whole dataset from per-episode probabilities.

    `episodes` has `task`, `dataset_from_index`, `dataset_to_index`. The last `drop_n_last_frames` frames of
    each episode get weight 0 (Diffusion cannot train on them, as in LeRobot's EpisodeAwareSampler).

    The rows may instead be parts of episodes (`dataset/interventions.py`: a person's and the policy's segments)
    with `episode_to_index` (where their episode ends, for `drop_n_last_frames`) and `weight` (a row's
    probability is multiplied by it); a part with no frame left to train on is then left out.
    """
    starts = episodes["dataset_from_index"].to_numpy(np.int64)
    parts = "episode_to_index" in episodes.columns
    episode_ends = episodes["episode_to_index" if parts else "dataset_to_index"].to_numpy(np.int64)
    ends = np.minimum(episodes["dataset_to_index"].to_numpy(np.int64), episode_ends - drop_n_last_frames)
    usable = np.maximum(ends - starts, 0)
    if parts and usable.any():
        keep = usable > 0
        episodes, starts, ends, usable = episodes[keep], starts[keep], ends[keep], usable[keep]
    if (usable == 0).any():
        short = list(episodes.index[usable == 0])
        raise AdaDemoError(
            f"episodes {short} are too short to train on (drop_n_last_frames={drop_n_last_frames})"
        )
    lengths = pd.Series(usable, index=episodes.index)
    unit_weights = episodes["weight"].to_numpy(np.float64) if "weight" in episodes.columns else None
    probs = scheme.episode_probabilities(episodes["task"], lengths, unit_weights)
    weights = np.zeros(num_frames, dtype=np.float64)
    for start, end, p, n in zip(starts, ends, probs, usable, strict=True):
        weights[start:end] = p / n
    return weights / weights.sum()
