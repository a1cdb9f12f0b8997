"""What two unrun levers could buy a paying arm at equal episodes, computed from its committed summaries.

An arm's equal-episode figure reads Uniform's curve at the arm's final episodes per task. Two kinds of episode
might be saved without changing what the arm collected:
- corrections in the rollout's own episode (`--demo_start=takeover`): each demonstration at a failed state merges
  into the rollout that found it, so its reset is saved (an upper bound: it assumes the expert always finishes
  from the takeover state, which MetaWorld's scripted experts do not on the weak tasks);
- no rollout on a task that never failed in any round (an upper bound: only hindsight knows which those are).

Each saving scales the arm's episodes down (spread over its rounds in proportion) and moves the reading point left
on Uniform's curve; what the arm collected, and so its success, stays what it was. Read as the report reads
equal episodes: both curves at the smaller of the two final costs.

    python benchmarks/episode_levers.py --summaries mt10_cost --arm costed_split
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import RESULTS
from efficiency_report import Run, diff_of_curves, fmt_diff, load_runs

from adademo_lerobot.core import costs
from adademo_lerobot.core.tables import table


def episodes_saved(run: Run) -> tuple[float, float]:
    """Per task: demonstrations at failed states (each a reset a correction in the rollout would save), and
    rollouts on the tasks that never failed in any round."""
    per_task = len(run.tasks)
    at_failures = sum(r["demos_added"] - r.get("extra", {}).get("fresh_demos", 0) for r in run.ledger)
    failed = {r["task"] for r in run.ledger if r.get("failures")}
    never_failing = sum(costs.rollouts(r) for r in run.ledger if r["task"] not in failed)
    return at_failures / per_task, never_failing / per_task


def gain_at_equal_episodes(mine: Run, uniform: Run, saved: float = 0.0) -> float:
    """Points over Uniform as the report reads equal episodes (both curves at the smaller of the two final
    costs), with `saved` episodes per task taken off the arm's, spread over its rounds in proportion."""
    x_mine = mine.cost("episodes")
    x = x_mine * (1 - saved / x_mine[-1])
    return diff_of_curves(x, mine.average, uniform.cost("episodes"), uniform.average)[0]


def levers(summaries: str, arm: str) -> str:
    runs, _ = load_runs(RESULTS / summaries)  # runs whose round 0 differs from Uniform's are left out
    seeds = sorted(s for a, s in runs if a == arm and ("uniform", s) in runs)
    rows, values = [], []
    for seed in seeds:
        mine, uniform = runs[(arm, seed)], runs[("uniform", seed)]
        at_failures, never_failing = episodes_saved(mine)
        value = [
            mine.cost("episodes")[-1],
            at_failures,
            never_failing,
            *(
                gain_at_equal_episodes(mine, uniform, saved)
                for saved in (0.0, at_failures, never_failing, at_failures + never_failing)
            ),
        ]
        values.append(value)
        rows.append([str(seed), *(f"{v:.1f}" if i < 3 else f"{v:+.1f}" for i, v in enumerate(value))])
    columns = np.array(values).T
    rows.append(
        [
            "mean [95 % t-interval]",
            *(f"{c.mean():.1f}" for c in columns[:3]),
            *(fmt_diff(c) for c in columns[3:]),
        ]
    )
    header = [
        "seed",
        "episodes per task",
        "demos at failed states",
        "rollouts on never-failing tasks",
        "equal episodes: as run",
        "corrections in the rollout",
        "no rollout on never-failing tasks",
        "both",
    ]
    return table(header, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--summaries", default="mt10_cost")
    parser.add_argument("--arm", default="costed_split")
    args = parser.parse_args()
    print(levers(args.summaries, args.arm))


if __name__ == "__main__":
    main()
