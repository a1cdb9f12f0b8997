"""The figures of `adademo-report`: success against demonstrations and against episodes, where the demonstrations
went, success per task, and what the evaluations cost."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure  # no pyplot: drawing into a file needs no GUI backend, and sets none

from adademo_lerobot.loop.run_results import RunResults


def plot_success_vs_demos(runs: list[RunResults], path: Path) -> None:
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    for run in runs:
        x = [run.demos[r].mean() for r in run.success.columns]
        y = [100 * run.success.loc["average", r] for r in run.success.columns]
        ax.plot(x, y, marker="o", label=f"{run.name} ({run.label})")
    ax.set_xlabel("average demos per task")
    ax.set_ylabel("average success rate (%)")
    ax.set_title("Success vs demonstrations (paper Fig. 1)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_success_vs_cost(runs: list[RunResults], path: Path) -> None:
    """Average success against what the rounds added per task: demonstrations, expert frames, episodes."""
    measures = ["demonstrations", "expert frames", "episodes"]
    fig = Figure(figsize=(5 * len(measures), 4))
    axes = fig.subplots(1, len(measures), sharey=True)
    for ax, measure in zip(axes, measures, strict=True):
        for run in runs:
            added = run.added_cost()
            ax.plot(added[measure], 100 * run.success.loc["average", added.index], marker="o", label=run.name)
        ax.set_xlabel(f"added {measure} per task")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("average success rate (%)")
    axes[-1].legend(fontsize=8)
    fig.suptitle("Success against each cost (episodes: expert episodes, kept or failed, + rollouts)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_allocation(run: RunResults, path: Path) -> None:
    rounds = list(run.demos.columns)
    new = run.demos.diff(axis=1)
    new[rounds[0]] = run.demos[rounds[0]]
    new = new.astype(int)
    fig = Figure(figsize=(max(6, len(run.tasks) * 0.9), 4))
    ax = fig.subplots()
    bottom = pd.Series(0, index=run.tasks)
    for r in rounds:
        ax.bar(run.tasks, new[r], bottom=bottom, label="initial" if r == 0 else f"round {r}")
        bottom += new[r]
    ax.set_ylabel("demonstrations")
    ax.set_title(f"Demo allocation per task — {run.name}")
    ax.tick_params(axis="x", rotation=30, labelsize=8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_per_task_success(run: RunResults, path: Path) -> None:
    fig = Figure(figsize=(max(6, len(run.tasks) * 0.9), 4))
    ax = fig.subplots()
    rounds = list(run.success.columns)
    width = 0.8 / len(rounds)
    for k, r in enumerate(rounds):
        ax.bar(
            [i + k * width for i in range(len(run.tasks))],
            100 * run.success.loc[run.tasks, r],
            width,
            label=f"round {r}",
        )
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(run.tasks))], run.tasks, rotation=30, fontsize=8)
    ax.set_ylabel("success rate (%)")
    ax.set_ylim(0, 105)
    ax.set_title(f"Per-task success per round — {run.name}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_eval_cost(runs: list[RunResults], path: Path) -> None:
    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    labels, evals, collects = [], [], []
    for run in runs:
        for r, g in run.ledger.groupby("round") if len(run.ledger) else []:
            labels.append(f"{run.name}\nr{r}")
            evals.append(g.eval_env_steps.sum())
            collects.append(g.collection_env_steps.sum())
    ax.bar(labels, evals, label="evaluation env steps")
    ax.bar(labels, collects, bottom=evals, label="expert collection env steps")
    ax.set_ylabel("env steps")
    ax.set_title("Cost of each expansion round")
    ax.tick_params(axis="x", labelsize=7)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
