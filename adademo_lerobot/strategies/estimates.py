"""A task's success rate as the strategies estimate it: a Beta posterior over the expansion rounds' evaluation
outcomes (never the fixed evaluation set, which is the test set): the last round's count fully, each round before it
weighs `decay` less per round (the policy was retrained in between)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from adademo_lerobot.dataset.ledger import read_round_evaluations

DEFAULT_DECAY = 0.5  # weight of a round's outcomes per round before the last


def prior_from_earlier_rounds(
    root: Path, round_index: int, task: str, decay: float = DEFAULT_DECAY
) -> tuple[float, float]:
    """Beta(alpha, beta) over the task's evaluation outcomes in rounds before `round_index` (Beta(1, 1) before
    any): a round r outcome weighs decay ** (round_index - 1 - r)."""
    alpha, beta = 1.0, 1.0
    for r in range(1, round_index):
        weight = decay ** (round_index - 1 - r)
        for entry in read_round_evaluations(root, r):
            if entry.get("type") == "eval" and entry.get("task") == task:
                alpha += weight * bool(entry["success"])
                beta += weight * (not entry["success"])
    return alpha, beta


def failure_mean(posterior: tuple[float, float]) -> float:
    alpha, beta = posterior
    return beta / (alpha + beta)


def estimated_success_rates(
    root: Path, round_index: int, tasks: list[str], decay: float = DEFAULT_DECAY
) -> dict[str, float]:
    """Each task's posterior mean success rate before round `round_index`."""
    return {t: 1 - failure_mean(prior_from_earlier_rounds(root, round_index, t, decay)) for t in tasks}


def count_outcomes(ctx, task: str, record, outcomes, posterior, answer_failure) -> tuple[float, float]:
    """Count a batch of evaluation outcomes in the task's record and Beta posterior, in order; each failure is
    answered by `answer_failure(task, seed, record)` (a demonstration) as it is counted. Returns the posterior."""
    alpha, beta = posterior
    for outcome in outcomes:
        record.eval_episodes += 1
        if outcome.success:
            record.successes += 1
            alpha += 1
        else:
            record.failures += 1
            beta += 1
            answer_failure(task, outcome.seed, record)
        ctx.progress(task, record)
    return alpha, beta


def knn_failure_vote(known: np.ndarray, failed: np.ndarray, query: np.ndarray, k: int) -> np.ndarray:
    """Each query state's share of failures among its k nearest known states (features standardized on the
    known states; constant features dropped; ties go to the earlier known state). Where no feature varies, every
    known state is as near as any other: the share of failures among them all."""
    mean, std = known.mean(0), known.std(0)
    keep = std > 1e-12
    if not keep.any():
        return np.full(len(query), failed.mean())
    a = (known[:, keep] - mean[keep]) / std[keep]
    b = (query[:, keep] - mean[keep]) / std[keep]
    distances = ((b[:, None, :] - a[None, :, :]) ** 2).sum(-1)
    nearest = np.argsort(distances, axis=1, kind="stable")[:, : min(k, len(a))]
    return failed[nearest].mean(1)


def allocate(total: int, weights: dict[str, float], caps: dict[str, int]) -> dict[str, int]:
    """Split `total` integer units across keys in proportion to `weights`, at most `caps[k]` each (water
    filling, then largest remainders; ties go to the earlier key). Sums to min(total, sum(caps))."""
    alloc = dict.fromkeys(weights, 0)
    left = min(total, sum(max(c, 0) for c in caps.values()))
    open_keys = [k for k in weights if caps[k] > 0]
    while left > 0 and open_keys:
        mass = sum(max(weights[k], 0.0) for k in open_keys)
        shares = {
            k: left * (max(weights[k], 0.0) / mass if mass > 0 else 1 / len(open_keys)) for k in open_keys
        }
        capped = [k for k in open_keys if alloc[k] + shares[k] >= caps[k]]
        if capped:  # these reach their cap: give it, and share the rest among the others
            for k in capped:
                left -= caps[k] - alloc[k]
                alloc[k] = caps[k]
            open_keys = [k for k in open_keys if k not in capped]
            continue
        floors = {k: int(shares[k]) for k in open_keys}
        for k in open_keys:
            alloc[k] += floors[k]
        left -= sum(floors.values())
        by_remainder = sorted(open_keys, key=lambda k: (-(shares[k] - floors[k]), list(weights).index(k)))
        for k in by_remainder[:left]:
            alloc[k] += 1
        left = 0
    return alloc
