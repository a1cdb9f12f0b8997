"""Will AdaDemo help on this task? How well a task's initial state predicts the policy's failure.

AdaDemo's principle B collects where the policy failed: that helps when failures concentrate in a region of
initial states (demonstrations there teach what is missing), and little when they look independent of the start
(a flaky grasp fails anywhere). Per task and per policy, every evaluated initial state and its outcome (the fixed
evaluation set of round r and the expansion evaluations of round r + 1 both ran policy r) give a data set; a
k-nearest-neighbour vote over the standardized initial states, cross-validated, scores each state's chance of
failing, and the area under the ROC curve (AUC) says how well that separates failures from successes: 0.5 is
chance, 1 is perfect. Its 95 % interval comes from resampling the states.

The reading: AUC >= 0.7 with an interval above 0.5: "failures concentrate in a region of initial states: demos at
failed states should help"; an interval that includes 0.5: "failures look independent of the start: expect little
over Uniform"; in between: "some concentration". Fewer than 5 failures in at most 5 % of the states: "(almost)
never fails"; otherwise fewer than 5 failures or successes: "too few outcomes to tell".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from adademo_lerobot.dataset.ledger import read_round_evaluations
from adademo_lerobot.strategies.estimates import knn_failure_vote

K = 5
FOLDS = 5
MIN_EACH = 5  # failures and successes needed for a reading


@dataclass
class Predictability:
    task: str
    states: int
    failures: int
    auc: float | None
    low: float | None
    high: float | None

    @property
    def reading(self) -> str:
        if self.auc is None and self.failures < MIN_EACH and self.failures <= 0.05 * self.states:
            return "(almost) never fails: little for AdaDemo to collect here"
        if self.auc is None:
            return "too few outcomes to tell"
        if self.low > 0.5 and self.auc >= 0.7:
            return "failures concentrate in a region of initial states: demos at failed states should help"
        if self.low <= 0.5:
            return "failures look independent of the start: expect little over Uniform"
        return "some concentration of failures: demos at failed states may help"


def auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve of `scores` for the positive `labels` (Mann-Whitney, ties counted half)."""
    ranks = pd.Series(scores).rank().to_numpy()
    positives = labels.astype(bool)
    n_pos, n_neg = positives.sum(), (~positives).sum()
    return float((ranks[positives].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def knn_failure_scores(states: np.ndarray, failed: np.ndarray, k: int = K, folds: int = FOLDS, seed: int = 0):
    """Each state's cross-validated score: the share of failures among its k nearest neighbours in the other
    folds (features standardized on the training folds; constant features dropped)."""
    rng = np.random.default_rng(seed)
    fold = rng.permutation(len(states)) % folds
    scores = np.zeros(len(states))
    for f in range(folds):
        train, test = fold != f, fold == f
        scores[test] = knn_failure_vote(states[train], failed[train], states[test], k)
    return scores


def predictability(
    task: str, groups: list[tuple[np.ndarray, np.ndarray]], boot: int = 1000
) -> Predictability:
    """AUC of failure from the initial state over `groups` (one (states, failed) per policy: scores come from
    each policy's own outcomes), with a 95 % bootstrap interval over states."""
    scores, labels = [], []
    for states, failed in groups:
        if len(states) >= 2 * FOLDS and 0 < failed.sum() < len(failed):
            scores.append(knn_failure_scores(states, failed))
            labels.append(failed)
    if not scores:
        n = sum(len(s) for s, _ in groups)
        return Predictability(task, n, int(sum(f.sum() for _, f in groups)), None, None, None)
    score, label = np.concatenate(scores), np.concatenate(labels)
    n_fail = int(label.sum())
    if n_fail < MIN_EACH or len(label) - n_fail < MIN_EACH:
        return Predictability(task, len(label), n_fail, None, None, None)
    rng = np.random.default_rng(0)
    values = []
    for _ in range(boot):
        pick = rng.integers(0, len(label), len(label))
        if 0 < label[pick].sum() < len(pick):
            values.append(auc(score[pick], label[pick]))
    low, high = np.percentile(values, [2.5, 97.5])
    return Predictability(task, len(label), n_fail, auc(score, label), float(low), float(high))


def evaluated_states(run_dir: Path, dataset_root: Path, base_round: int = 0) -> dict[int, pd.DataFrame]:
    """Per policy round r: every state it was evaluated on (task, initial_state, success), from the fixed set of
    round r and the expansion evaluations of round r + 1 (whose states are rebuilt from their seeds)."""
    from adademo_lerobot.dataset.metadata import load_suite_config
    from adademo_lerobot.suites import make_suite

    suite = None
    out: dict[int, list[pd.DataFrame]] = {}
    for path in sorted(Path(run_dir).glob("eval/round-*/eval_episodes.parquet")):
        r = int(path.parent.name.split("-")[1])
        out.setdefault(r, []).append(pd.read_parquet(path, columns=["task", "initial_state", "success"]))
    for r in list(out):
        entries = [
            e for e in read_round_evaluations(dataset_root, base_round + r + 1) if e.get("type") == "eval"
        ]
        if not entries:
            continue
        suite = suite or make_suite(load_suite_config(dataset_root))
        rows = [
            {
                "task": e["task"],
                "initial_state": suite.sample_initial_state(e["task"], e["seed"]),
                "success": e["success"],
            }
            for e in entries
            if e["task"] in suite.tasks
        ]
        out[r].append(pd.DataFrame(rows))
    return {r: pd.concat(frames, ignore_index=True) for r, frames in out.items()}


def run_predictability(run_dir: Path, dataset_root: Path, tasks: list[str], base_round: int = 0):
    by_round = evaluated_states(run_dir, dataset_root, base_round)
    results = []
    for task in tasks:
        groups = []
        for frame in by_round.values():
            rows = frame[frame.task == task]
            if len(rows):
                groups.append(
                    (
                        np.stack([np.asarray(s, np.float64) for s in rows.initial_state]),
                        ~rows.success.to_numpy(),
                    )
                )
        results.append(predictability(task, groups))
    return results, by_round


def plot_failure_map(by_round: dict[int, pd.DataFrame], tasks: list[str], path: Path) -> None:
    """Per task, the initial states of the latest policy's evaluations on their first two principal components,
    failures in red."""
    from matplotlib.figure import Figure

    latest = by_round[max(by_round)]
    cols = min(4, len(tasks))
    rows = -(-len(tasks) // cols)
    fig = Figure(figsize=(3.2 * cols, 3 * rows))
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for ax, task in zip(axes, tasks, strict=False):
        frame = latest[latest.task == task]
        ax.set_title(task, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        if len(frame) < 3:
            continue
        states = np.stack([np.asarray(s, np.float64) for s in frame.initial_state])
        centred = states - states.mean(0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        xy = centred @ vt[:2].T if vt.shape[0] >= 2 else np.c_[centred @ vt[:1].T, np.zeros(len(states))]
        ok = frame.success.to_numpy()
        ax.scatter(xy[ok, 0], xy[ok, 1], s=8, c="tab:green", label="success")
        ax.scatter(xy[~ok, 0], xy[~ok, 1], s=8, c="tab:red", label="failure")
    for ax in axes[len(tasks) :]:
        ax.set_visible(False)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=7)
    fig.suptitle(
        f"Initial states of the round-{max(by_round)} policy's evaluations (first two principal components)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def predictability_json(results: list[Predictability]) -> str:
    return json.dumps([r.__dict__ | {"reading": r.reading} for r in results], indent=1)
