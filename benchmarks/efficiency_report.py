"""The data-efficiency report: success against what each arm paid, per seed, paired with Uniform.

Read from the committed summaries (`benchmarks/results/<folder>/seed<S>-<arm>.json`, one per finished arm and
seed, all from one machine): every arm's curve of average success against the cost it added per task after the
shared round 0, in demonstrations, expert frames (env steps under the expert's control, failed attempts included)
and episodes (demonstrations + every evaluation episode of the expansion rounds). From the curves, per seed:

- the paired difference to Uniform after round 3 (at the arm's own cost; equal demonstrations for arms that spend
  the same budget) and at equal expert frames (both curves read at the smaller of the two final frame counts);
- the cost at which the arm first reaches Uniform's final average, as a fraction of Uniform's cost, per measure.

Differences get a 95 % t-interval over seeds (paired), ratios a 95 % bootstrap interval over seeds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MEASURES = {"demos": "demonstrations", "frames": "expert frames", "episodes": "episodes"}
# Two-sided 95 % quantiles of Student's t, by degrees of freedom (1..30).
T95 = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
       2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042]  # fmt: skip


@dataclass
class Run:
    """One arm on one seed: success per task and round, and what each round added (per task, on average)."""

    arm: str
    seed: int
    tasks: list[str]
    success: np.ndarray  # task x round
    added: dict[str, np.ndarray]  # measure -> cumulative added per task after round 0..R (starts at 0)
    ledger: list[dict]
    # per episode of the expansion rounds: task, round, source, start_step, length (if exported)
    episodes: list[dict]
    predictability: dict[str, dict]  # task -> failure predictability from the initial state (if exported)

    @property
    def average(self) -> np.ndarray:  # by round
        return self.success.mean(axis=0)


def cumulative_added(ledger: list[dict], rounds: int, cost, task: str | None = None) -> np.ndarray:
    """`cost(row)` summed over the ledger's rows (of `task`, or all) per round, cumulated: the total added after
    round 0..rounds-1 (the ledger's first expansion round is round 1)."""
    first = min(row["round"] for row in ledger)
    per_round = np.zeros(rounds)
    for row in ledger:
        if task is None or row["task"] == task:
            per_round[row["round"] - first + 1] += cost(row)
    return np.cumsum(per_round)


COSTS = {  # measure -> what a ledger row (one task, one round) spent in it
    "demos": lambda row: row["demos_added"],
    "frames": lambda row: row["collection_env_steps"],
    "episodes": lambda row: row["demos_added"] + row.get("eval_episodes_run", row["eval_episodes"]),
}


def load_run(summary: dict) -> Run:
    tasks = summary["tasks"]
    success = np.array([summary["success"][t] for t in tasks], dtype=float)
    rounds = success.shape[1]
    added = {m: cumulative_added(summary["ledger"], rounds, COSTS[m]) / len(tasks) for m in MEASURES}
    return Run(
        summary["arm"],
        summary["seed"],
        tasks,
        success,
        added,
        summary["ledger"],
        summary.get("episodes", []),
        summary.get("predictability", {}),
    )


def load_runs(folder: Path) -> dict[tuple[str, int], Run]:
    runs = {}
    for path in sorted(folder.glob("seed*-*.json")):
        summary = json.loads(path.read_text())
        runs[(summary["arm"], summary["seed"])] = load_run(summary)
    task_sets = {tuple(r.tasks) for r in runs.values()}
    if len(task_sets) > 1:
        raise SystemExit(f"the summaries in {folder} are of different task sets: {sorted(task_sets)}")
    return runs


def cost_to_reach(x: np.ndarray, y: np.ndarray, target: float) -> float | None:
    """The cost at which the curve (x, y) first reaches `target`, interpolated linearly between rounds."""
    if y[0] >= target:
        return float(x[0])
    for k in range(1, len(x)):
        if y[k] >= target:
            return float(x[k - 1] + (target - y[k - 1]) / (y[k] - y[k - 1]) * (x[k] - x[k - 1]))
    return None


def value_at(x: np.ndarray, y: np.ndarray, level: float) -> float:
    """The curve's success at cost `level` (within its range), interpolated linearly."""
    return float(np.interp(level, x, y))


def t_interval(values: np.ndarray) -> tuple[float, float]:
    """Mean and half-width of the 95 % t-interval (nan half-width for a single value)."""
    values = np.asarray(values, float)
    if len(values) < 2:
        return float(values.mean()), float("nan")
    half = T95[min(len(values) - 1, len(T95)) - 1] * values.std(ddof=1) / np.sqrt(len(values))
    return float(values.mean()), float(half)


def bootstrap_interval(values: np.ndarray, n: int = 10000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile interval of the mean, resampling seeds."""
    values = np.asarray(values, float)
    rng = np.random.default_rng(seed)
    means = rng.choice(values, size=(n, len(values)), replace=True).mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


@dataclass
class Comparison:
    """An arm against Uniform over the seeds both finished."""

    arm: str
    seeds: list[int]
    final_diff: np.ndarray  # per seed, points, after round 3
    demos_diff: np.ndarray  # per seed, points, at equal demonstrations
    frames_diff: np.ndarray  # per seed, points, at equal expert frames
    frames_level: np.ndarray  # per seed, the expert frames per task compared at
    ratio: dict[
        str, list[float | None]
    ]  # measure -> per seed, cost to reach Uniform's final / Uniform's cost


def diff_at_equal(mine: Run, uniform: Run, measure: str) -> tuple[float, float]:
    """Points of average success over Uniform with both curves read at the same cost (the smaller of the two
    final costs in `measure`), and that cost."""
    level = min(mine.added[measure][-1], uniform.added[measure][-1])
    return 100 * (
        value_at(mine.added[measure], mine.average, level)
        - value_at(uniform.added[measure], uniform.average, level)
    ), level


def compare(runs: dict[tuple[str, int], Run], arm: str, seeds: list[int]) -> Comparison:
    final, demos_diff, frames_diff, levels, ratio = [], [], [], [], {m: [] for m in MEASURES}
    for s in seeds:
        mine, uniform = runs[(arm, s)], runs[("uniform", s)]
        final.append(100 * (mine.average[-1] - uniform.average[-1]))
        demos_diff.append(diff_at_equal(mine, uniform, "demos")[0])
        diff, level = diff_at_equal(mine, uniform, "frames")
        frames_diff.append(diff)
        levels.append(level)
        for m in MEASURES:
            reached = cost_to_reach(mine.added[m], mine.average, uniform.average[-1])
            ratio[m].append(None if reached is None else reached / uniform.added[m][-1])
    return Comparison(
        arm, seeds, np.array(final), np.array(demos_diff), np.array(frames_diff), np.array(levels), ratio
    )


def fmt_diff(values: np.ndarray) -> str:
    mean, half = t_interval(values)
    interval = "" if np.isnan(half) else f" [{mean - half:+.1f}, {mean + half:+.1f}]"
    return f"{mean:+.1f}{interval}"


def fmt_ratio(values: list[float | None]) -> str:
    reached = np.array([v for v in values if v is not None])
    if not len(reached):
        return f"not reached (0/{len(values)} seeds)"
    lo, hi = bootstrap_interval(reached) if len(reached) > 1 else (reached[0], reached[0])
    missing = "" if len(reached) == len(values) else f"; not reached on {len(values) - len(reached)} seed(s)"
    return f"{reached.mean():.2f}x [{lo:.2f}, {hi:.2f}]{missing}"


def correction_lines(
    runs: dict[tuple[str, int], Run], arm: str, seeds: list[int], tasks: list[str]
) -> list[str]:
    """Per task, for an arm with corrections: how often the expert failed from a takeover state, where the
    expert took over and how long corrections were (against Uniform's demonstrations)."""
    rows = []
    for t in tasks:
        ledger = [row for s in seeds for row in runs[(arm, s)].ledger if row["task"] == t]
        uniform = [row for s in seeds for row in runs[("uniform", s)].ledger if row["task"] == t]
        if any("takeover_failures" in r for r in ledger):  # takeover failures, answered from the start or not
            failed = sum(r["takeover_failures"] for r in ledger)
            tried = sum(r["corrections"] for r in ledger) + failed
        else:  # the first protocol: a failed takeover got nothing (an expert failure)
            failed = sum(r["expert_failures"] for r in ledger)
            tried = sum(r["demos_added"] + r["expert_failures"] for r in ledger)
        frames = sum(r.get("demo_frames", 0) for r in ledger) / max(1, sum(r["demos_added"] for r in ledger))
        uniform_frames = sum(r["collection_env_steps"] for r in uniform) / max(
            1, sum(r["demos_added"] for r in uniform)
        )
        lost = f"{wasted_share(ledger):.0f} % / {wasted_share(uniform):.0f} %"
        steps = [e["start_step"] for s in seeds for e in runs[(arm, s)].episodes if e["task"] == t]
        rows.append(
            f"| {t} | {failed}/{tried} ({100 * failed / max(1, tried):.0f} %) | "
            f"{f'{np.mean(steps):.0f}' if steps else '-'} | {frames:.0f} | {uniform_frames:.0f} | {lost} | "
            f"{fmt_task_ratio([task_frames_ratio(runs[(arm, s)], runs[('uniform', s)], t) for s in seeds])} |"
        )
    everything = [row for s in seeds for row in runs[(arm, s)].ledger]
    uniform_all = [row for s in seeds for row in runs[("uniform", s)].ledger]
    return [
        "| task | expert failed from the takeover state | mean takeover step | frames per correction "
        "| Uniform's expert frames per demo | expert frames in failed attempts: this arm / Uniform "
        "| reaches Uniform's final on this task with: expert frames (seeds) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
        f"| all | | | | | {wasted_share(everything):.0f} % / {wasted_share(uniform_all):.0f} % | |",
    ]


def task_frames_ratio(mine: Run, uniform: Run, task: str) -> float | None:
    """On one task: the expert frames the arm spent to reach Uniform's final success there, over Uniform's."""

    def frames(run: Run) -> np.ndarray:
        return cumulative_added(run.ledger, run.success.shape[1], COSTS["frames"], task)

    i = mine.tasks.index(task)
    reached = cost_to_reach(frames(mine), mine.success[i], uniform.success[i][-1])
    return None if reached is None else reached / max(1.0, frames(uniform)[-1])


def fmt_task_ratio(values: list[float | None]) -> str:
    reached = [v for v in values if v is not None]
    mean = f"{np.mean(reached):.2f}x" if reached else "never"
    return f"{mean} ({len(reached)}/{len(values)} reached)"


def wasted_share(ledger: list[dict]) -> float:
    """The share of expert frames spent in attempts that failed (not recorded): collection steps not in a demo."""
    spent = sum(r["collection_env_steps"] for r in ledger)
    return 100 * (spent - sum(r.get("demo_frames", 0) for r in ledger)) / max(1, spent)


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Rank correlation of two paired samples (ties get their mean rank)."""
    import pandas as pd

    return float(np.corrcoef(pd.Series(a).rank(), pd.Series(b).rank())[0, 1])


def predictability_lines(
    runs: dict[tuple[str, int], Run],
    arms: list[str],
    seeds_of: dict[str, list[int]],
    tasks: list[str],
    labels: dict[str, str],
) -> tuple[list[str], dict[str, float]]:
    """Does failure predictability from the initial state tell where adaptive collection gains? Per task the AUC
    (mean over every exported run's estimate) beside each arm's paired gain over Uniform after round 3, and the
    rank correlation over tasks (also returned, per arm). For comparison, the same correlation for the round-0
    failure rate (Uniform's seeds): the room a task leaves to gain, which the AUC does not measure."""
    aucs = {
        t: [
            r.predictability[t]["auc"]
            for r in runs.values()
            if r.predictability.get(t, {}).get("auc") is not None
        ]
        for t in tasks
    }
    if not any(aucs.values()):
        return ["No summary has failure predictability yet (re-export with `data_efficiency.py export`)."], {}
    mean_auc = np.array([np.mean(aucs[t]) if aucs[t] else np.nan for t in tasks])
    gains = {}
    for arm in arms:
        seeds = [s for s in seeds_of[arm] if s in seeds_of.get("uniform", [])]
        if arm != "uniform" and seeds:
            gains[arm] = np.array(
                [
                    100
                    * np.mean(
                        [runs[(arm, s)].success[i, -1] - runs[("uniform", s)].success[i, -1] for s in seeds]
                    )
                    for i in range(len(tasks))
                ]
            )
    base = [runs[("uniform", s)].success[:, 0] for s in seeds_of.get("uniform", [])]
    failures = 100 * (1 - np.mean(base, axis=0)) if base else np.full(len(tasks), np.nan)
    rows = [
        f"| {t} | "
        + (f"{mean_auc[i]:.2f} ({len(aucs[t])})" if aucs[t] else "-")
        + f" | {failures[i]:.0f} | "
        + " | ".join(f"{g[i]:+.0f}" for g in gains.values())
        + " |"
        for i, t in enumerate(tasks)
    ]
    known = ~np.isnan(mean_auc)
    rho = {arm: spearman(mean_auc[known], g[known]) for arm, g in gains.items() if known.sum() >= 3}
    rho_failures = {arm: spearman(failures[known], gains[arm][known]) for arm in rho}
    return [
        "| task | AUC (estimates) | round-0 failures % | "
        + " | ".join(f"{labels.get(a, a)}: gain" for a in gains)
        + " |",
        "| --- | --- | --- | " + " | ".join("---" for _ in gains) + " |",
        *rows,
        "",
        f"Spearman rank correlation of AUC and gain over {int(known.sum())} tasks: "
        + "; ".join(f"{labels.get(arm, arm)} {r:+.2f}" for arm, r in rho.items())
        + ". Of the round-0 failure rate and gain, over the same tasks: "
        + "; ".join(f"{labels.get(arm, arm)} {r:+.2f}" for arm, r in rho_failures.items())
        + ".",
    ], rho


def plot_curves(runs, seeds: dict[str, list[int]], labels: dict[str, str], path: Path) -> None:
    """Success against each cost measure, one curve per arm (mean and std over that arm's `seeds`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(MEASURES), figsize=(5.2 * len(MEASURES), 4), sharey=True)
    for ax, (measure, name) in zip(axes, MEASURES.items(), strict=True):
        for arm, arm_seeds in seeds.items():
            xs = np.array([runs[(arm, s)].added[measure] for s in arm_seeds])
            ys = 100 * np.array([runs[(arm, s)].average for s in arm_seeds])
            ax.errorbar(
                xs.mean(0), ys.mean(0), yerr=ys.std(0), marker="o", capsize=3, label=labels.get(arm, arm)
            )
        ax.set_xlabel(f"{name} added per task (after the shared round 0)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("average success rate (%)")
    # Below the panels: inside one, the long arm names hide the first rounds' points.
    handles, names = axes[-1].get_legend_handles_labels()
    fig.legend(handles, names, fontsize=8, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0.04 + 0.035 * ((len(names) + 1) // 2), 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(
    folder: Path,
    labels: dict[str, str],
    title: str,
    header: list[str],
    takeover_arms: set[str],
    out: Path,
) -> str:
    """The report of every arm in `folder` (markdown at `out`, plot beside it); keeps a hand-written `## Reading`."""
    from adademo_lerobot.tables import table

    runs = load_runs(folder)
    seeds_of = {arm: sorted(s for a, s in runs if a == arm) for arm, _ in runs}
    if "uniform" not in seeds_of:
        raise SystemExit(f"no Uniform summary in {folder}: nothing to compare with")
    arms = [a for a in labels if a in seeds_of] + sorted(set(seeds_of) - set(labels))
    # Each arm over the seeds it shares with Uniform (so its curve and Uniform's have the same round 0s),
    # Uniform over all of its own.
    curve_seeds = {a: [s for s in seeds_of[a] if s in seeds_of["uniform"]] for a in arms}
    curve_seeds = {a: ss for a, ss in curve_seeds.items() if ss}
    tasks = next(iter(runs.values())).tasks
    rounds = next(iter(runs.values())).success.shape[1]
    lines = [f"# {title}", "", *header, ""]
    lines += [
        "Seeds per arm: "
        + "; ".join(f"{labels.get(a, a)} {', '.join(map(str, seeds_of[a]))}" for a in arms)
        + ".",
        "",
        "## Curves (each arm over the seeds it and Uniform both finished; Uniform over all of its own)",
        "",
        "Average success on the same 50 fixed initial states per task, mean ± std over seeds; in brackets what the "
        "expansion rounds added per task: demonstrations / expert frames.",
        "",
    ]
    rows = []
    for arm, common in curve_seeds.items():
        cells = []
        for r in range(rounds):
            ys = [100 * runs[(arm, s)].average[r] for s in common]
            demos = np.mean([runs[(arm, s)].added["demos"][r] for s in common])
            frames = np.mean([runs[(arm, s)].added["frames"][r] for s in common])
            cells.append(f"{np.mean(ys):.1f} ± {np.std(ys):.1f} ({demos:.1f} / {frames:.0f})")
        rows.append([labels.get(arm, arm), ", ".join(map(str, common)), *cells])
    lines += [table(["arm", "seeds", *(f"round {r}" for r in range(rounds))], rows, aligned=False)]
    plot_curves(runs, curve_seeds, labels, out.with_suffix(".png"))
    comparisons = {}
    for arm in arms:
        seeds = [s for s in seeds_of[arm] if s in seeds_of["uniform"]]
        if arm != "uniform" and seeds:
            comparisons[arm] = compare(runs, arm, seeds)
    lines += [
        "",
        "## Against Uniform, paired by seed",
        "",
        "Differences in points of average success (mean over seeds [95 % t-interval]); 'equal demonstrations' and "
        "'equal expert frames': both curves read at the smaller of the two arms' final cost per task (after "
        "round 3 is at equal demonstrations for arms that add the same number); 'reaches Uniform's final average with': "
        "the arm's cost there over Uniform's final cost (mean [95 % bootstrap interval over seeds]).",
        "",
    ]
    rows = []
    for arm, c in comparisons.items():
        rows.append(
            [
                labels.get(arm, arm),
                len(c.seeds),
                fmt_diff(c.final_diff),
                fmt_diff(c.demos_diff),
                f"{fmt_diff(c.frames_diff)} @ {c.frames_level.mean():.0f}",
                *(fmt_ratio(c.ratio[m]) for m in MEASURES),
            ]
        )
    lines += [
        table(
            [
                "arm",
                "seeds",
                "after round 3",
                "at equal demonstrations",
                "at equal expert frames",
                *(f"reaches Uniform's with: {n}" for n in MEASURES.values()),
            ],
            rows,
            aligned=False,
        ),
        "",
        "Per seed, after round 3: "
        + "; ".join(
            f"{labels.get(a, a)} " + ", ".join(f"{d:+.1f}" for d in c.final_diff)
            for a, c in comparisons.items()
        )
        + ".",
        "",
        "## Per task (round 3: mean over each arm's seeds, paired difference to Uniform in brackets)",
        "",
    ]
    rows = []
    for t, task in enumerate(tasks):
        cells = []
        for arm in arms:
            seeds = [s for s in seeds_of[arm] if s in seeds_of["uniform"]]
            mine = np.array([runs[(arm, s)].success[t, -1] for s in seeds])
            base = np.array([runs[("uniform", s)].success[t, -1] for s in seeds])
            cells.append(
                f"{100 * mine.mean():.0f}"
                + ("" if arm == "uniform" else f" ({100 * (mine - base).mean():+.0f})")
            )
        rows.append([task, *cells])
    lines += [table(["task", *(labels.get(a, a) for a in arms)], rows, aligned=False)]
    for arm in arms:
        if arm in takeover_arms:
            lines += [
                "",
                f"Corrections of {labels.get(arm, arm)} (seeds {', '.join(map(str, seeds_of[arm]))}):",
                "",
            ]
            lines += correction_lines(
                runs, arm, [s for s in seeds_of[arm] if s in seeds_of["uniform"]], tasks
            )
    lines += [
        "",
        "## Will adaptive collection help on a task? Failure predictability against gains",
        "",
        "Per task: how well the initial state predicts the policy's failure (cross-validated 5-nearest-neighbour "
        "AUC, `adademo_lerobot/failure_map.py`, mean over the runs' estimates, each over every state its policies "
        "were evaluated on) and each arm's paired gain over Uniform after round 3, in points.",
        "",
    ]
    predictability, correlations = predictability_lines(runs, arms, seeds_of, tasks, labels)
    lines += predictability
    lines += ["", "## Goals", "", "Data efficiency:", ""] + efficiency_goal_lines(
        comparisons, labels, correlations
    )
    if any(a in takeover_arms for a in comparisons):
        lines += ["", "Corrections (takeover arms):", ""] + goal_lines(comparisons, takeover_arms, labels)
    lines += [
        "",
        f"![success against demonstrations, expert frames and episodes]({out.with_suffix('.png').name})",
    ]
    reading = out.read_text().partition("\n## Reading")[2] if out.exists() else ""
    text = "\n".join(lines) + "\n" + (f"\n## Reading{reading}" if reading else "")
    out.write_text(text)
    return text


def best_arm(comparisons: dict[str, Comparison], arms: list[str], key) -> str:
    """Of `arms`, those with the most seeds, then the highest `key(arm)`."""
    most = max(len(comparisons[a].seeds) for a in arms)
    return max((a for a in arms if len(comparisons[a].seeds) == most), key=key)


def five_points_line(measure: str, diffs: np.ndarray) -> str:
    """The goal '>= Uniform + 5 points after 3 rounds at equal `measure`, 95 % interval above 0, >= 5 seeds'."""
    mean, half = t_interval(diffs)
    ok = len(diffs) >= 5 and mean >= 5 and mean - half > 0
    short = [] if len(diffs) >= 5 else [f"{len(diffs)} seeds of the 5 asked"]
    short += [] if mean >= 5 else [f"{mean:+.1f} points, {5 - mean:.1f} short"]
    short += [] if np.isnan(half) or mean - half > 0 else ["the interval includes 0"]
    return (
        f"- At equal {measure} >= Uniform + 5 points after 3 rounds, 95 % interval above 0: "
        + ("met" if ok else f"missed ({'; '.join(short)})")
        + f": {fmt_diff(diffs)}."
    )


def efficiency_goal_lines(
    comparisons: dict[str, Comparison], labels: dict[str, str], correlations: dict[str, float]
) -> list[str]:
    """The data-efficiency goals, computed for the best arm (most seeds, then the best difference at equal
    demonstrations): Uniform's final average with <= 1/3 of Uniform's added demonstrations; >= Uniform + 5 points
    at equal demonstrations after 3 rounds with a 95 % interval above 0 (>= 5 seeds); and whether failure
    predictability points the same way as the per-task gains."""
    if not comparisons:
        return ["No arm has finished a seed beside Uniform yet."]
    arm = best_arm(comparisons, list(comparisons), lambda a: comparisons[a].demos_diff.mean())
    c = comparisons[arm]
    lines = [f"Best arm: {labels.get(arm, arm)} ({len(c.seeds)} seeds)."]
    reached = [v for v in c.ratio["demos"] if v is not None]
    ratio = fmt_ratio(c.ratio["demos"])
    verdict = "met" if reached and len(reached) == len(c.seeds) and np.mean(reached) <= 1 / 3 else "missed"
    lines.append(
        f"- Uniform's final average with <= 1/3 of Uniform's added demonstrations: {verdict} ({ratio})."
    )
    lines.append(five_points_line("demonstrations", c.demos_diff))
    if arm in correlations:
        r = correlations[arm]
        lines.append(
            f"- Failure predictability and per-task gain, rank correlation: {r:+.2f} "
            + ("(the direction the reading predicts)." if r > 0 else "(against the reading's direction).")
        )
    return lines


def goal_lines(
    comparisons: dict[str, Comparison], takeover_arms: set[str], labels: dict[str, str]
) -> list[str]:
    """The corrections issue's goals, computed: the best takeover arm (most seeds, then the best difference at
    equal expert frames) against Uniform and against the best initial-state arm."""
    takeover = [a for a in comparisons if a in takeover_arms]
    initial = [a for a in comparisons if a not in takeover_arms]
    if not takeover:
        return ["No takeover arm has finished a seed yet."]
    arm = best_arm(comparisons, takeover, lambda a: comparisons[a].frames_diff.mean())
    c = comparisons[arm]
    frames = [v for v in c.ratio["frames"] if v is not None]
    lines = [f"Best takeover arm: {labels.get(arm, arm)} ({len(c.seeds)} seeds)."]
    if frames:
        ratio = np.mean(frames)
        verdict = (
            "met" if ratio <= 1 / 3 and len(frames) == len(c.seeds) else f"missed ({ratio:.2f}x, goal 0.33x)"
        )
        lines.append(f"- Uniform's final average with <= 1/3 of Uniform's added expert frames: {verdict}.")
    else:
        lines.append(
            "- Uniform's final average with <= 1/3 of Uniform's added expert frames: missed (never reached)."
        )
    if initial:
        rival = best_arm(comparisons, initial, lambda a: comparisons[a].final_diff.mean())
        # Per seed both ran: fewer demos to reach Uniform's final average (an arm that never reached it within
        # its rounds needed more than it added, so the other one, if it reached it, needed fewer).
        theirs = dict(zip(comparisons[rival].seeds, comparisons[rival].ratio["demos"], strict=True))
        pairs = [(r, theirs[s]) for s, r in zip(c.seeds, c.ratio["demos"], strict=True) if s in theirs]
        fewer = sum(r is not None and (t is None or r < t) for r, t in pairs)
        shown = "; ".join(
            f"{'-' if r is None else f'{r:.3f}x'} vs {'not reached' if t is None else f'{t:.3f}x'}"
            for r, t in pairs
        )
        verdict = "met" if pairs and fewer == len(pairs) else "missed"
        lines.append(
            f"- ... with fewer demonstrations than the best initial-state arm ({labels.get(rival, rival)}): "
            f"{verdict}, fewer on {fewer} of the {len(pairs)} seeds both ran (of Uniform's added demos, per seed: "
            f"{shown})."
        )
    lines.append(five_points_line("expert frames", c.frames_diff))
    return lines
