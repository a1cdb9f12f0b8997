"""The data-efficiency report: success against what each arm paid, per seed, paired with Uniform.

Read from the committed summaries (`benchmarks/results/<folder>/seed<S>-<arm>.json`, one per finished arm and
seed, a seed's arms all from one kind of CPU): every arm's curve of average success against the cost it added per task after the
shared round 0, in demonstrations, expert frames (env steps under the expert's control, failed attempts included)
and episodes (what a person resets the scene for: expert episodes, kept or failed, and policy rollouts; the
cost model is `adademo_lerobot/core/costs.py`). From the curves, per seed:

- the paired difference to Uniform after round 3 and at equal demonstrations, expert frames and episodes (both
  curves read at the smaller of the two final costs);
- the cost at which the arm first reaches Uniform's final average, as a fraction of Uniform's cost, per
  measure, and the break-even rollout cost c*, each read two ways: interpolated inside the round where the
  curve crosses Uniform's final, and at the first round whose trained policy reaches it.

Every mean over seeds gets a 95 % t-interval (paired by seed). Where a summary does not record expert episodes
exactly, every figure built on them is the range over their bounds.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from adademo_lerobot.core import costs

MEASURES = {"demos": "demonstrations", "frames": "expert frames", "episodes": "episodes"}
READINGS = {"interpolated": "interpolated", "trained": "at trained policies"}
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
    # measure -> cumulative added per task after round 0..R (starts at 0): demos, frames, rollouts,
    # expert_episodes, episodes; the last two at their lower bound where a summary does not record them
    # exactly
    added: dict[str, np.ndarray]
    added_high: dict[str, np.ndarray]  # the same at the upper bound (equal to `added` when exact)
    ledger: list[dict]
    # per episode of the expansion rounds: task, round, source, start_step, length (if exported)
    episodes: list[dict]
    predictability: dict[str, dict]  # task -> failure predictability from the initial state (if exported)
    bounds_reason: str = ""  # why expert episodes are known only within bounds (if they are)

    @property
    def average(self) -> np.ndarray:  # by round
        return self.success.mean(axis=0)

    def cost(self, measure: str, high: bool = False) -> np.ndarray:
        return (self.added_high if high else self.added)[measure]

    @property
    def exact(self) -> bool:
        return all(np.array_equal(self.added[m], self.added_high[m]) for m in self.added)


def cumulative_added(ledger: list[dict], rounds: int, cost, task: str | None = None) -> np.ndarray:
    """`cost(row)` summed over the ledger's rows (of `task`, or all) per round, cumulated: the total added after
    round 0..rounds-1 (the ledger's first expansion round is round 1)."""
    first = min(row["round"] for row in ledger)
    per_round = np.zeros(rounds)
    for row in ledger:
        if task is None or row["task"] == task:
            per_round[row["round"] - first + 1] += cost(row)
    return np.cumsum(per_round)


COSTS = {  # measure -> what a ledger row (one task, one round) spent in it, as recorded
    "demos": lambda row: row["demos_added"],
    "frames": lambda row: row["collection_env_steps"],
    "rollouts": costs.rollouts,
}


def load_run(summary: dict) -> Run:
    tasks = summary["tasks"]
    success = np.array([summary["success"][t] for t in tasks], dtype=float)
    rounds, ledger = success.shape[1], summary["ledger"]
    settings = summary.get("settings") or {}
    step_limit = (settings.get("suite") or {}).get("max_episode_steps")
    takeover = settings.get("demo_start") == "takeover"
    # Frames kept per task and round, from the exported episodes where a ledger row lacks `demo_frames`.
    kept = Counter()
    for e in summary.get("episodes", []):
        kept[(e["task"], e["round"])] += e["length"]

    def expert(row: dict, bound: int) -> int:
        frames = kept[(row["task"], row["round"])] if summary.get("episodes") else None
        return costs.expert_episodes(row, step_limit, takeover, frames)[bound]

    added = {m: cumulative_added(ledger, rounds, cost) / len(tasks) for m, cost in COSTS.items()}
    high = dict(added)
    for bound, view in enumerate((added, high)):
        view["expert_episodes"] = cumulative_added(ledger, rounds, lambda r, b=bound: expert(r, b)) / len(
            tasks
        )
        view["episodes"] = view["expert_episodes"] + view["rollouts"]
    reasons = []
    if not summary.get("episodes") and any("demo_frames" not in r for r in ledger):
        reasons.append("no frames kept per round")
    if takeover and any("takeover_failures" not in r for r in ledger):
        reasons.append("no takeover failures (the first takeover protocol)")
    run = Run(
        summary["arm"],
        summary["seed"],
        tasks,
        success,
        added,
        high,
        ledger,
        summary.get("episodes", []),
        summary.get("predictability", {}),
    )
    if not run.exact:
        run.bounds_reason = "; ".join(reasons) or "expert frames not in whole step limits"
    return run


def load_runs(folder: Path) -> tuple[dict[tuple[str, int], Run], list[tuple[str, int]]]:
    """The summaries in `folder`, and the (arm, seed) left out: a run whose round 0 differs from Uniform's on
    the same seed on some task did not start from the same policy (trained on another CPU type), so pairing it
    would compare machines, not arms."""
    runs = {}
    for path in sorted(folder.glob("seed*-*.json")):
        summary = json.loads(path.read_text())
        runs[(summary["arm"], summary["seed"])] = load_run(summary)
    task_sets = {tuple(r.tasks) for r in runs.values()}
    if len(task_sets) > 1:
        raise SystemExit(f"the summaries in {folder} are of different task sets: {sorted(task_sets)}")
    unpaired = [
        (arm, seed)
        for (arm, seed), run in runs.items()
        if arm != "uniform"
        and ("uniform", seed) in runs
        and not np.array_equal(run.success[:, 0], runs[("uniform", seed)].success[:, 0])
    ]
    return {key: run for key, run in runs.items() if key not in unpaired}, unpaired


def cost_to_reach(x: np.ndarray, y: np.ndarray, target: float, trained_only: bool = False) -> float | None:
    """The cost at which the curve (x, y) first reaches `target`, interpolated linearly between rounds
    (trained only: at the first round whose policy reaches it)."""
    at = costs.crossing(y, target, trained_only)
    return None if at is None else costs.read(x, at)


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


@dataclass
class PerSeed:
    """A figure per seed, paired with Uniform: its smallest and largest value over the bounds of expert
    episodes a summary does not record exactly (the same when every count is exact); None where the arm never
    reached Uniform's final average."""

    low: list[float | None]
    high: list[float | None]

    @property
    def exact(self) -> bool:
        return self.low == self.high


def spread(figure, mine: Run, uniform: Run, *args) -> tuple[float | None, float | None]:
    """`figure(mine, uniform, *args, mine_high, uniform_high)` with each run's expert episodes at their lower
    and upper bound: its smallest and largest value (c* and the ratios are monotone in each bound, so these
    bound it)."""
    values = [figure(mine, uniform, *args, a, u) for a in (False, True) for u in (False, True)]
    return (None, None) if values[0] is None else (min(values), max(values))


def per_seed(pairs: list[tuple[float | None, float | None]]) -> PerSeed:
    return PerSeed([p[0] for p in pairs], [p[1] for p in pairs])


@dataclass
class Comparison:
    """An arm against Uniform over the seeds both finished."""

    arm: str
    seeds: list[int]
    final_diff: np.ndarray  # per seed, points, after round 3
    demos_diff: np.ndarray  # per seed, points, at equal demonstrations
    frames_diff: np.ndarray  # per seed, points, at equal expert frames
    frames_level: np.ndarray  # per seed, the expert frames per task compared at
    episodes_diff: PerSeed  # per seed, points, at equal episodes
    episodes_level: PerSeed  # per seed, the episodes per task compared at
    ratio: dict[
        str, dict[str, PerSeed]
    ]  # reading -> measure -> cost to reach Uniform's final / Uniform's cost
    cstar: dict[str, PerSeed]  # reading -> the break-even rollout cost c*
    uniform_gain: (
        np.ndarray
    )  # per seed, points: Uniform's final average minus round 0's (which every arm shares)

    @property
    def flat_seeds(self) -> list[int]:
        """Seeds where Uniform's added demonstrations did not raise its average: every arm starts at or above
        Uniform's final there, so it 'reaches' it before adding anything (ratio 0, c* infinite by construction)."""
        return [s for s, gain in zip(self.seeds, self.uniform_gain, strict=True) if gain <= 0]


def diff_at_equal(
    mine: Run, uniform: Run, measure: str, mine_high: bool = False, uniform_high: bool = False
) -> tuple[float, float]:
    """Points of average success over Uniform (or another arm) with both curves read at the same cost (the
    smaller of the two final costs in `measure`), and that cost."""
    return diff_of_curves(
        mine.cost(measure, mine_high), mine.average, uniform.cost(measure, uniform_high), uniform.average
    )


def diff_of_curves(x_mine, y_mine, x_other, y_other) -> tuple[float, float]:
    """Points of `y_mine` over `y_other`, both curves read at the smaller of their final costs, and that cost."""
    level = min(x_mine[-1], x_other[-1])
    return 100 * (value_at(x_mine, y_mine, level) - value_at(x_other, y_other, level)), float(level)


def diff_at_equal_points(mine: Run, uniform: Run, measure: str, mine_high: bool, uniform_high: bool) -> float:
    return diff_at_equal(mine, uniform, measure, mine_high, uniform_high)[0]


def equal_level(mine: Run, uniform: Run, measure: str, mine_high: bool, uniform_high: bool) -> float:
    return diff_at_equal(mine, uniform, measure, mine_high, uniform_high)[1]


def reach_ratio(
    mine: Run, uniform: Run, measure: str, reading: str, mine_high: bool = False, uniform_high: bool = False
) -> float | None:
    """The arm's cost when it first reaches Uniform's final average, over Uniform's final cost."""
    at = costs.crossing(mine.average, uniform.average[-1], reading == "trained")
    if at is None:
        return None
    return costs.read(mine.cost(measure, mine_high), at) / uniform.cost(measure, uniform_high)[-1]


def break_even(
    mine: Run, uniform: Run, reading: str, mine_high: bool = False, uniform_high: bool = False
) -> float | None:
    """c* = (X_U - X) / R at the point the arm first reaches Uniform's final average (None: never)."""
    at = costs.crossing(mine.average, uniform.average[-1], reading == "trained")
    if at is None:
        return None
    return costs.break_even(
        costs.read(mine.cost("expert_episodes", mine_high), at),
        costs.read(mine.cost("rollouts"), at),
        float(uniform.cost("expert_episodes", uniform_high)[-1]),
    )


def compare(runs: dict[tuple[str, int], Run], arm: str, seeds: list[int]) -> Comparison:
    final, demos_diff, frames_diff, levels = [], [], [], []
    episodes_diff, episodes_level = [], []
    ratio = {r: {m: [] for m in MEASURES} for r in READINGS}
    cstar = {r: [] for r in READINGS}
    gains = []
    for s in seeds:
        mine, uniform = runs[(arm, s)], runs[("uniform", s)]
        final.append(100 * (mine.average[-1] - uniform.average[-1]))
        gains.append(100 * (uniform.average[-1] - uniform.average[0]))
        demos_diff.append(diff_at_equal(mine, uniform, "demos")[0])
        diff, level = diff_at_equal(mine, uniform, "frames")
        frames_diff.append(diff)
        levels.append(level)
        episodes_diff.append(spread(diff_at_equal_points, mine, uniform, "episodes"))
        episodes_level.append(spread(equal_level, mine, uniform, "episodes"))
        for reading in READINGS:
            for m in MEASURES:
                ratio[reading][m].append(spread(reach_ratio, mine, uniform, m, reading))
            cstar[reading].append(spread(break_even, mine, uniform, reading))
    return Comparison(
        arm,
        seeds,
        np.array(final),
        np.array(demos_diff),
        np.array(frames_diff),
        np.array(levels),
        per_seed(episodes_diff),
        per_seed(episodes_level),
        {r: {m: per_seed(v) for m, v in by.items()} for r, by in ratio.items()},
        {r: per_seed(v) for r, v in cstar.items()},
        np.array(gains),
    )


def fmt_mean(values, spec: str, unit: str = "") -> str:
    """Mean [95 % t-interval] (the mean alone for one value)."""
    mean, half = t_interval(values)
    interval = "" if np.isnan(half) else f" [{mean - half:{spec}}, {mean + half:{spec}}]"
    return f"{mean:{spec}}{unit}{interval}"


def fmt_diff(values: np.ndarray) -> str:
    return fmt_mean(values, "+.1f")


def fmt_bounds(low: np.ndarray, high: np.ndarray, spec: str, unit: str = "") -> str:
    """A mean with its interval, or, where the values are only known within bounds, the same at each bound."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    if np.array_equal(low, high):
        return fmt_mean(low, spec, unit)
    return f"{fmt_mean(low, spec, unit)} to {fmt_mean(high, spec, unit)}"


def fmt_diff_span(values: PerSeed) -> str:
    return fmt_bounds(values.low, values.high, "+.1f")


def seeds_text(n: int) -> str:
    return f"{n} seed{'' if n == 1 else 's'}"


def fmt_ratio(values: PerSeed, note: bool = True) -> str:
    """Mean cost ratio [95 % t-interval over the seeds that reached Uniform's final], and where it did not."""
    reached = [i for i, v in enumerate(values.low) if v is not None]
    if not reached:
        return f"not reached (0/{seeds_text(len(values.low))})"
    missing = len(values.low) - len(reached)
    text = fmt_bounds([values.low[i] for i in reached], [values.high[i] for i in reached], ".2f", "x")
    return text + (f"; not reached on {seeds_text(missing)}" if missing and note else "")


def fmt_both_ratios(c: Comparison, measure: str) -> str:
    """Both readings (a seed reaches Uniform's final in both or in neither: missing seeds are said once)."""
    interpolated, trained = c.ratio["interpolated"][measure], c.ratio["trained"][measure]
    missing = sum(v is None for v in interpolated.low)
    if missing == len(interpolated.low):
        return fmt_ratio(interpolated)
    return f"{fmt_ratio(interpolated, note=False)}; trained {fmt_ratio(trained, note=False)}" + (
        f"; not reached on {seeds_text(missing)}" if missing else ""
    )


def fmt_cstar(values: PerSeed) -> str:
    """c* over seeds: the mean [95 % t-interval] of the finite values (at both bounds of expert episodes where
    they are not exact), and on how many seeds it was infinite or never reached."""
    n = len(values.low)
    both = list(zip(values.low, values.high, strict=True))
    finite = [(lo, hi) for lo, hi in both if lo is not None and math.isfinite(lo) and math.isfinite(hi)]
    parts = []
    if finite:
        low, high = np.array([p[0] for p in finite]), np.array([p[1] for p in finite])
        text = fmt_bounds(low, high, ".2f") + ("" if len(finite) == n else f" over {seeds_text(len(finite))}")
        if high.mean() < 0:
            text += " (negative: does not pay off even with free rollouts)"
        parts.append(text)
    reached = [(lo, hi) for lo, hi in both if lo is not None]
    infinite = sum(lo == math.inf for lo, _ in reached)
    never_pays = sum(hi == -math.inf for _, hi in reached)
    counts = {
        "pays off at any rollout cost": infinite,
        "does not pay off even with free rollouts": never_pays,
        "infinite at one bound of expert episodes only": len(reached) - len(finite) - infinite - never_pays,
        "never reaches Uniform's final": n - len(reached),
    }
    parts += [f"{what} on {seeds_text(k)}" for what, k in counts.items() if k]
    return "; ".join(parts)


def mean_or_never(values: list[float | None]) -> float:
    """A per-seed figure's mean, to rank arms (minus infinite if it never reached the target on a seed)."""
    if any(v is None for v in values):
        return -math.inf
    with np.errstate(invalid="ignore"):
        mean = float(np.mean(values))
    return -math.inf if math.isnan(mean) else mean


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
            f"{fmt_task_ratios(runs, arm, seeds, t)} |"
        )
    everything = [row for s in seeds for row in runs[(arm, s)].ledger]
    uniform_all = [row for s in seeds for row in runs[("uniform", s)].ledger]
    return [
        "| task | expert failed from the takeover state | mean takeover step | frames per correction "
        "| Uniform's expert frames per demo | expert frames in failed attempts: this arm / Uniform "
        "| reaches Uniform's final on this task with: expert frames, interpolated; at trained policies "
        "(seeds) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
        f"| all | | | | | {wasted_share(everything):.0f} % / {wasted_share(uniform_all):.0f} % | |",
    ]


def task_frames_ratio(mine: Run, uniform: Run, task: str, trained_only: bool = False) -> float | None:
    """On one task: the expert frames the arm spent to reach Uniform's final success there, over Uniform's
    (interpolated inside the round, or at the first round whose trained policy reaches it)."""

    def frames(run: Run) -> np.ndarray:
        return cumulative_added(run.ledger, run.success.shape[1], COSTS["frames"], task)

    i = mine.tasks.index(task)
    reached = cost_to_reach(frames(mine), mine.success[i], uniform.success[i][-1], trained_only)
    return None if reached is None else reached / max(1.0, frames(uniform)[-1])


def fmt_task_ratio(values: list[float | None]) -> str:
    reached = [v for v in values if v is not None]
    mean = f"{np.mean(reached):.2f}x" if reached else "never"
    return f"{mean} ({len(reached)}/{len(values)} reached)"


def fmt_task_ratios(runs: dict[tuple[str, int], Run], arm: str, seeds: list[int], task: str) -> str:
    """Both readings of one task's frames ratio (a seed reaches the target in both or in neither)."""
    values = {
        trained: [task_frames_ratio(runs[(arm, s)], runs[("uniform", s)], task, trained) for s in seeds]
        for trained in (False, True)
    }
    first, trained = ([v for v in values[k] if v is not None] for k in (False, True))
    if not first:
        return fmt_task_ratio(values[False])
    return f"{np.mean(first):.2f}x; {np.mean(trained):.2f}x ({len(first)}/{len(seeds)} reached)"


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


def cost_lines(
    runs: dict[tuple[str, int], Run],
    curve_seeds: dict[str, list[int]],
    comparisons: dict[str, Comparison],
    labels: dict[str, str],
) -> list[str]:
    """Per arm: what it added per task after round 3 (mean [95 % t-interval] over its seeds), and c*."""
    rows = []
    for arm, seeds in curve_seeds.items():

        def final(measure: str, high: bool = False, arm: str = arm, seeds: list[int] = seeds) -> np.ndarray:
            return np.array([runs[(arm, s)].cost(measure, high)[-1] for s in seeds])

        c = comparisons.get(arm)
        rows.append(
            [
                labels.get(arm, arm),
                len(seeds),
                fmt_mean(final("demos"), ".1f"),
                fmt_mean(final("frames"), ".0f"),
                fmt_bounds(final("expert_episodes"), final("expert_episodes", True), ".1f"),
                fmt_mean(final("rollouts"), ".1f"),
                fmt_bounds(final("episodes"), final("episodes", True), ".1f"),
                *(("-", "-") if c is None else (fmt_cstar(c.cstar[r]) for r in READINGS)),
            ]
        )
    from adademo_lerobot.core.tables import table

    lines = [
        table(
            [
                "arm",
                "seeds",
                "demonstrations",
                "expert frames",
                "expert episodes",
                "rollouts",
                "episodes",
                "c*, interpolated",
                "c*, at trained policies",
            ],
            rows,
            aligned=False,
        ),
        "",
        "Per seed, c* interpolated / at trained policies: "
        + "; ".join(
            f"{labels.get(a, a)} "
            + ", ".join(
                f"{fmt_seed_cstar(c.cstar['interpolated'], i)} / {fmt_seed_cstar(c.cstar['trained'], i)}"
                for i in range(len(c.seeds))
            )
            for a, c in comparisons.items()
        )
        + ".",
    ]
    lines += kept_rollout_lines(runs, curve_seeds, labels)
    inexact = {labels.get(a, a): r.bounds_reason for (a, s), r in sorted(runs.items()) if not r.exact}
    if inexact:
        lines += [
            "",
            "Expert episodes known only within bounds (`adademo_lerobot/core/costs.py`), from the summaries of "
            + "; ".join(f"{arm} ({why})" for arm, why in inexact.items())
            + ": every figure built on them is given at both bounds (low to high), and the episodes panel of "
            "the figure plots the lower.",
        ]
    return lines


def kept_rollout_lines(
    runs: dict[tuple[str, int], Run], curve_seeds: dict[str, list[int]], labels: dict[str, str]
) -> list[str]:
    """The successful rollouts arms kept as data (`--keep_successes`) per task, which cost no episode of their own
    (they are among the rollouts above); nothing when no arm kept any."""
    kept = {
        arm: np.array(
            [sum(r.get("policy_episodes_kept", 0) for r in runs[(arm, s)].ledger) for s in seeds], float
        )
        / len(runs[(arm, seeds[0])].tasks)
        for arm, seeds in curve_seeds.items()
    }
    kept = {arm: values for arm, values in kept.items() if values.any()}
    if not kept:
        return []
    return [
        "",
        "Successful rollouts kept as data (`--keep_successes`, `adademo/source=policy`) per task after round 3, "
        "among the rollouts above: "
        + "; ".join(f"{labels.get(a, a)} {fmt_mean(v, '.1f')}" for a, v in kept.items())
        + ".",
    ]


def fmt_seed_cstar(values: PerSeed, i: int) -> str:
    def one(v: float | None) -> str:
        return "never" if v is None else {math.inf: "any cost", -math.inf: "not even free"}.get(v, f"{v:.2f}")

    low, high = one(values.low[i]), one(values.high[i])
    return low if low == high else f"{low} to {high}"


def added_per_task(run: Run, measure: str) -> np.ndarray:
    """What the expansion rounds added per task (in `run.tasks` order) after the last round, in `measure`."""
    rounds = run.success.shape[1]
    return np.array([cumulative_added(run.ledger, rounds, COSTS[measure], t)[-1] for t in run.tasks])


def where_episodes_went(
    runs: dict[tuple[str, int], Run],
    arms: list[str],
    seeds_of: dict[str, list[int]],
    tasks: list[str],
    labels,
) -> list[str]:
    """Per task and arm, what the expansion rounds spent there: demonstrations / policy rollouts after the last
    round, mean over the arm's seeds paired with Uniform (why an arm gains or loses on a task)."""
    from adademo_lerobot.core.tables import table

    mean_added = {}  # (arm, measure) -> per task, mean over the arm's seeds paired with Uniform
    for arm in arms:
        seeds = [s for s in seeds_of[arm] if s in seeds_of["uniform"]]
        for m in ("demos", "rollouts"):
            mean_added[(arm, m)] = np.mean([added_per_task(runs[(arm, s)], m) for s in seeds], axis=0)
    rows = [
        [task, *(f"{mean_added[(a, 'demos')][i]:.1f} / {mean_added[(a, 'rollouts')][i]:.1f}" for a in arms)]
        for i, task in enumerate(tasks)
    ]
    return [
        "## Where the episodes went (per task after the last round: demonstrations / rollouts, mean over seeds)",
        "",
        table(["task", *(labels.get(a, a) for a in arms)], rows, aligned=False),
    ]


# A task at or above this success at round 0 (mean over Uniform's seeds) is solved: that demonstrations do not
# raise it says nothing about whether they could.
SOLVED = 0.95


def demonstration_return_lines(
    runs: dict[tuple[str, int], Run], arms: list[str], seeds_of: dict[str, list[int]], labels
) -> list[str]:
    """Do a task's demonstrations raise it? Per task, Uniform's return on its added demonstrations (points of
    success per 10, mean over its seeds) beside each arm's demonstrations there as a multiple of Uniform's
    (paired seeds); then the share of each arm's added demonstrations that went to tasks Uniform's did not raise
    (return <= 0), the solved ones (round 0 >= `SOLVED`) apart from those still failing. Principle A gives the
    most to the weakest task, which pays only where that task also rises with demonstrations: this says, per
    task, where an allocation bought nothing."""
    from adademo_lerobot.core.tables import table

    uniform = [runs[("uniform", s)] for s in seeds_of["uniform"]]
    tasks = uniform[0].tasks
    start = np.mean([r.success[:, 0] for r in uniform], axis=0)
    paired = {a: [s for s in seeds_of[a] if s in seeds_of["uniform"]] for a in arms}
    demos = {a: [added_per_task(runs[(a, s)], "demos") for s in seeds] for a, seeds in paired.items()}
    uniform_demos = dict(zip(seeds_of["uniform"], demos["uniform"], strict=True))
    with np.errstate(divide="ignore", invalid="ignore"):  # a task Uniform added nothing to: nan, shown as -
        returns = np.array(
            [1000 * (r.success[:, -1] - r.success[:, 0]) / uniform_demos[r.seed] for r in uniform]
        )
        known = np.isfinite(returns)
        # The mean over the seeds with a return (np.nanmean warns where there is none).
        mean_return = np.where(known, returns, 0).sum(axis=0) / known.sum(axis=0)
        multiples = {
            a: np.mean([d / uniform_demos[s] for d, s in zip(demos[a], paired[a], strict=True)], axis=0)
            for a in arms
            if a != "uniform"
        }
    not_raised = {  # nan compares False: a task without a return is never 'not raised'
        f"solved at round 0 (>= {100 * SOLVED:.0f} %)": (mean_return <= 0) & (start >= SOLVED),
        "still failing": (mean_return <= 0) & (start < SOLVED),
    }
    rows = [
        [
            task,
            f"{100 * start[i]:.0f} -> {100 * np.mean([r.success[i, -1] for r in uniform]):.0f}",
            "-" if np.isnan(mean_return[i]) else f"{mean_return[i]:+.1f}",
            *(f"{m[i]:.2f}x" if np.isfinite(m[i]) else "-" for m in multiples.values()),
        ]
        for i, task in enumerate(tasks)
    ]
    shares = [
        f"{kind} ({', '.join(t for t, f in zip(tasks, mask, strict=True) if f)}): "
        + ", ".join(
            f"{labels.get(a, a)} {100 * np.mean([d[mask].sum() / max(d.sum(), 1) for d in demos[a]]):.0f} %"
            for a in arms
        )
        for kind, mask in not_raised.items()
        if mask.any()
    ]
    return [
        "## Do demonstrations raise a task? Uniform's return per task, and where each arm put its demonstrations",
        "",
        "Per task: Uniform's success at round 0 and after the last round (%, mean over its seeds), its return "
        "((last - round 0) per 10 demonstrations it added there, in points, mean over its seeds; one training's "
        "chance moves a task by several points, so read the sign where it is large) and each arm's "
        "demonstrations there over Uniform's (paired seeds).",
        "",
        table(
            [
                "task",
                "Uniform, round 0 -> last, %",
                "Uniform: points per 10 demonstrations",
                *(f"{labels.get(a, a)}: demonstrations over Uniform's" for a in multiples),
            ],
            rows,
            aligned=False,
        ),
        "",
        "Share of the added demonstrations that went to tasks Uniform's demonstrations did not raise: "
        + "; ".join(shares)
        + "."
        if shares
        else "Uniform's demonstrations raised every task they were added to (return above 0).",
    ]


def flat_uniform_lines(runs: dict[tuple[str, int], Run], seeds: list[int]) -> list[str]:
    """Where Uniform's added demonstrations did not raise its average, said once: every arm starts at or above
    Uniform's final there, so 'reaches Uniform's final' holds at round 0 and its goals are not read."""
    flat = [s for s in seeds if runs[("uniform", s)].average[-1] <= runs[("uniform", s)].average[0]]
    if not flat:
        return []
    curves = "; ".join(
        f"seed {s} {100 * runs[('uniform', s)].average[0]:.1f} -> {100 * runs[('uniform', s)].average[-1]:.1f} %"
        for s in flat
    )
    return [
        "",
        f"Uniform's added demonstrations did not raise its average on {len(flat)} of {len(seeds)} seeds "
        f"({curves}): every arm starts there at or above Uniform's final, so it 'reaches' it with nothing added "
        "(0x, c* infinite) by construction; the goals against Uniform's final are not read while such a seed "
        "is in the pairing.",
    ]


def write_report(
    folder: Path,
    labels: dict[str, str],
    title: str,
    header: list[str],
    takeover_arms: set[str],
    out: Path,
) -> str:
    """The report of every arm in `folder` (markdown at `out`, plot beside it); keeps a hand-written `## Reading`."""
    from adademo_lerobot.core.tables import table

    runs, unpaired = load_runs(folder)
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
    ]
    if unpaired:
        lines += [
            "Left out, their round 0 differs from Uniform's on the same seed (trained on another CPU type, "
            "so not from the same policy): "
            + "; ".join(f"{labels.get(a, a)} seed {s}" for a, s in sorted(unpaired))
            + ".",
            "",
        ]
    lines += [
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
        "Differences in points of average success (mean over seeds [95 % t-interval]); 'equal "
        "demonstrations', 'equal expert frames' and 'equal episodes': both curves read at the smaller of the "
        "two arms' final cost per task, @ that cost (after round 3 is at equal demonstrations for arms that "
        "add the same number); "
        "'reaches Uniform's final average with': the arm's cost there over Uniform's final cost (mean [95 % "
        "t-interval over seeds]), read interpolated inside the round where the arm's curve crosses Uniform's "
        "final, then ('trained') at the first round whose trained policy reaches it. Episodes: what a person "
        "resets the scene for (next section).",
        "",
    ]
    rows = []
    for arm, c in comparisons.items():
        level = fmt_bounds(c.episodes_level.low, c.episodes_level.high, ".1f").split(" [")[0]
        rows.append(
            [
                labels.get(arm, arm),
                len(c.seeds),
                fmt_diff(c.final_diff),
                fmt_diff(c.demos_diff),
                f"{fmt_diff(c.frames_diff)} @ {c.frames_level.mean():.0f}",
                f"{fmt_diff_span(c.episodes_diff)} @ {level}",
                *(fmt_both_ratios(c, m) for m in MEASURES),
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
                "at equal episodes",
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
        *flat_uniform_lines(runs, sorted({s for c in comparisons.values() for s in c.seeds})),
        "",
        "## What a person pays: episodes, and the break-even rollout cost c*",
        "",
        "On a robot every episode needs a person to reset the scene. Episodes: every expert attempt (a "
        "demonstration or a failed attempt; from a fresh initial state or a failed rollout's) and every "
        "policy rollout an expansion round ran; a correction from the point of failure "
        "(`--demo_start=takeover`) is part of the rollout it corrects, and a demonstration from the initial "
        "state after a failed takeover is one more episode; the fixed evaluation set is free for every arm. "
        "Per task after round 3, mean [95 % t-interval] over each arm's seeds. c*: the largest cost of a "
        "policy rollout, in expert episodes, at which the arm reaches Uniform's final average at no more "
        "total cost than Uniform: (X_U - X) / R, with X expert episodes and R rollouts where the arm first "
        "reaches Uniform's final (interpolated, or at trained policies) and X_U Uniform's expert episodes to "
        "its final, per seed paired with Uniform's, then mean [95 % t-interval] over seeds.",
        "",
        *cost_lines(runs, curve_seeds, comparisons, labels),
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
    lines += ["", *where_episodes_went(runs, arms, seeds_of, tasks, labels)]
    lines += ["", *demonstration_return_lines(runs, arms, seeds_of, labels)]
    lines += [
        "",
        "## Will adaptive collection help on a task? Failure predictability against gains",
        "",
        "Per task: how well the initial state predicts the policy's failure (cross-validated 5-nearest-neighbour "
        "AUC, `adademo_lerobot/loop/failure_map.py`, mean over the runs' estimates, each over every state its policies "
        "were evaluated on) and each arm's paired gain over Uniform after round 3, in points.",
        "",
    ]
    predictability, correlations = predictability_lines(runs, arms, seeds_of, tasks, labels)
    lines += predictability
    lines += ["", "## Goals", "", "Data efficiency:", ""] + efficiency_goal_lines(
        comparisons, labels, correlations
    )
    lines += ["", "Cost in episodes (a person resets the scene for each):", ""]
    lines += cost_goal_lines(comparisons, labels) + [principle_b_line(runs, seeds_of, labels)]
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


def points_goal_line(measure: str, diffs, goal: float = 5, min_seeds: int = 5) -> str:
    """The goal '>= Uniform + `goal` points after 3 rounds at equal `measure`, 95 % interval above 0' (and at
    least `min_seeds` seeds). `diffs`: per seed, or a PerSeed whose bounds must both meet it."""
    low, high = (diffs.low, diffs.high) if isinstance(diffs, PerSeed) else (diffs, diffs)
    (mean, half), (mean_high, half_high) = t_interval(low), t_interval(high)
    shown = fmt_diff_span(diffs) if isinstance(diffs, PerSeed) else fmt_diff(diffs)
    seeds = f", >= {min_seeds} seeds" if min_seeds else ""
    enough = len(low) >= min_seeds
    # Met on the least favourable bound of expert episodes, missed when even the most favourable misses.
    reasons = [] if enough else [f"{seeds_text(len(low))} of the {min_seeds} asked"]
    if np.isnan(half_high):
        reasons.append("no interval from one seed")
    elif mean_high - half_high <= 0:
        reasons.append("the interval is not above 0")
    if enough and mean >= goal and not np.isnan(half) and mean - half > 0:
        verdict = "met"
    elif mean_high < goal:
        verdict = f"missed by {goal - mean_high:.1f} points" + (f" ({'; '.join(reasons)})" if reasons else "")
    elif reasons:
        verdict = f"missed ({'; '.join(reasons)})"
    else:
        verdict = "not decided within the bounds of expert episodes"
    return (
        f"- At equal {measure} >= Uniform + {goal:g} points after 3 rounds, 95 % interval above 0{seeds}: "
        f"{verdict}: {shown}."
    )


def five_points_line(measure: str, diffs: np.ndarray) -> str:
    return points_goal_line(measure, diffs, 5, 5)


def flat_verdict(c: Comparison) -> str | None:
    """The verdict of a goal read against Uniform's final where Uniform's added data did not raise it."""
    if not c.flat_seeds:
        return None
    return (
        f"not read: on {len(c.flat_seeds)} of {len(c.seeds)} seeds Uniform's final average is at or under "
        "round 0's, where the arm starts (reached with nothing added, by construction)"
    )


def ratio_verdict(values: PerSeed, goal: float, c: Comparison | None = None) -> str:
    """'met' when the arm reaches Uniform's final on every seed with a mean cost ratio <= goal (at both
    bounds), else by how much it missed; not read where Uniform's final is no higher than round 0 (`c`)."""
    if c is not None and (flat := flat_verdict(c)):
        return flat
    reached = [v for v in values.low if v is not None]
    if len(reached) < len(values.low):
        return f"missed: never reached on {len(values.low) - len(reached)} of {len(values.low)} seeds"
    low = float(np.mean(values.low))
    high = float(np.mean(values.high))
    if high <= goal:
        return "met"
    if low > goal:
        return f"missed by {low - goal:.2f}x"
    return "not decided within the bounds of expert episodes"


def cstar_verdict(values: PerSeed, goal: float = 1.0, c: Comparison | None = None) -> str:
    """'met' when the arm reaches Uniform's final on every seed with a mean c* >= goal (at both bounds); not
    read where Uniform's final is no higher than round 0 (`c`)."""
    if c is not None and (flat := flat_verdict(c)):
        return flat
    never = sum(v is None for v in values.low)
    if never:
        return f"missed: never reached on {never} of {len(values.low)} seeds"
    low, high = mean_or_never(values.low), mean_or_never(values.high)
    if low >= goal:
        return "met"
    if high < goal:
        return f"missed by {goal - high:.2f}"
    return "not decided within the bounds of expert episodes"


def never_reached(c: Comparison, reading: str) -> int:
    """On how many seeds the arm never reaches Uniform's final average (in `reading`)."""
    return sum(v is None for v in c.ratio[reading]["demos"].low)


def efficiency_goal_lines(
    comparisons: dict[str, Comparison], labels: dict[str, str], correlations: dict[str, float]
) -> list[str]:
    """The data-efficiency goals, computed for the best arm (most seeds, then the best difference at equal
    demonstrations): Uniform's final average with <= 1/3 of Uniform's added demonstrations (both readings);
    >= Uniform + 5 points at equal demonstrations after 3 rounds with a 95 % interval above 0 (>= 5 seeds);
    and whether failure predictability points the same way as the per-task gains."""
    if not comparisons:
        return ["No arm has finished a seed beside Uniform yet."]
    arm = best_arm(comparisons, list(comparisons), lambda a: comparisons[a].demos_diff.mean())
    c = comparisons[arm]
    lines = [f"Best arm: {labels.get(arm, arm)} ({seeds_text(len(c.seeds))})."]
    readings = [
        f"{name} {ratio_verdict(c.ratio[r]['demos'], 1 / 3, c)}"
        + (f" ({fmt_ratio(c.ratio[r]['demos'], note=False)})" if never_reached(c, r) < len(c.seeds) else "")
        for r, name in READINGS.items()
    ]
    lines.append(
        f"- Uniform's final average with <= 1/3 of Uniform's added demonstrations: {'; '.join(readings)}."
    )
    lines.append(five_points_line("demonstrations", c.demos_diff))
    if arm in correlations:
        r = correlations[arm]
        lines.append(
            f"- Failure predictability and per-task gain, rank correlation: {r:+.2f} "
            + ("(the direction the reading predicts)." if r > 0 else "(against the reading's direction).")
        )
    return lines


def cost_goal_lines(comparisons: dict[str, Comparison], labels: dict[str, str]) -> list[str]:
    """The cost goals, computed: the best arm by c* (most seeds, then the highest mean c* interpolated)
    reaches Uniform's final average with at most 1.0x Uniform's episodes (c* >= 1) and at most 1/3 of its
    demonstrations; the best arm at equal episodes is >= Uniform + 3 points after 3 rounds, interval above
    0."""
    if not comparisons:
        return ["No arm has finished a seed beside Uniform yet."]
    arm = best_arm(
        comparisons, list(comparisons), lambda a: mean_or_never(comparisons[a].cstar["interpolated"].low)
    )
    c = comparisons[arm]
    readings = [
        f"{name}, c* {fmt_cstar(c.cstar[r])} ({cstar_verdict(c.cstar[r], c=c)}; "
        f"{fmt_ratio(c.ratio[r]['episodes'], note=False)} Uniform's episodes) and "
        f"{fmt_ratio(c.ratio[r]['demos'], note=False)} of its demonstrations "
        f"({ratio_verdict(c.ratio[r]['demos'], 1 / 3, c)})"
        if never_reached(c, r) < len(c.seeds)
        else f"{name}, never reaches Uniform's final ({seeds_text(len(c.seeds))})"
        for r, name in READINGS.items()
    ]
    met = {
        name: cstar_verdict(c.cstar[r], c=c) == "met"
        and ratio_verdict(c.ratio[r]["demos"], 1 / 3, c) == "met"
        for r, name in READINGS.items()
    }
    overall = (
        "met"
        if all(met.values())
        else "missed"
        if not any(met.values())
        else "; ".join(f"{'met' if ok else 'missed'} {name}" for name, ok in met.items())
    )
    lines = [
        f"Best arm by c*: {labels.get(arm, arm)} ({seeds_text(len(c.seeds))}).",
        "- Uniform's final average with at most 1.0x Uniform's episodes (c* >= 1) and at most 1/3 of its "
        f"demonstrations, 95 % intervals: {overall}: {'; '.join(readings)}.",
    ]
    arm = best_arm(comparisons, list(comparisons), lambda a: float(np.mean(comparisons[a].episodes_diff.low)))
    lines += [
        f"Best arm at equal episodes: {labels.get(arm, arm)} ({seeds_text(len(comparisons[arm].seeds))}).",
        points_goal_line("episodes", comparisons[arm].episodes_diff, goal=3, min_seeds=0),
    ]
    return lines


def principle_b_line(runs: dict[tuple[str, int], Run], seeds_of: dict[str, list[int]], labels: dict) -> str:
    """Principle B alone: A + B (arm `budgeted`) minus A (arm `task_only`: the same budget and evaluations,
    every failure answered from a fresh state), paired by seed, at equal demonstrations and at equal
    episodes."""
    what = "- Principle B on its own, A + B minus A (budgeted minus task_only)"
    missing = [a for a in ("budgeted", "task_only") if a not in seeds_of]
    seeds = [s for s in seeds_of.get("budgeted", []) if s in seeds_of.get("task_only", [])]
    if missing or not seeds:
        return f"{what}: not measured (no summaries of {' and '.join(missing) or 'both on one seed'})."
    pairs = [(runs[("budgeted", s)], runs[("task_only", s)]) for s in seeds]
    demos = np.array([diff_at_equal(b, a, "demos")[0] for b, a in pairs])
    episodes = per_seed([spread(diff_at_equal_points, b, a, "episodes") for b, a in pairs])
    return (
        f"{what}, paired over {len(seeds)} seeds (no target: measured): at equal demonstrations "
        f"{fmt_diff(demos)} points, at equal episodes {fmt_diff_span(episodes)} points."
    )


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
    lines = [f"Best takeover arm: {labels.get(arm, arm)} ({seeds_text(len(c.seeds))})."]
    readings = [
        f"{name} {ratio_verdict(c.ratio[r]['frames'], 1 / 3, c)} "
        f"({fmt_ratio(c.ratio[r]['frames'], note=False)}, goal 0.33x)"
        for r, name in READINGS.items()
    ]
    lines.append(
        f"- Uniform's final average with <= 1/3 of Uniform's added expert frames: {'; '.join(readings)}."
    )
    if initial:
        rival = best_arm(comparisons, initial, lambda a: comparisons[a].final_diff.mean())
        # Per seed both ran: fewer demos to reach Uniform's final average (an arm that never reached it within
        # its rounds needed more than it added, so the other one, if it reached it, needed fewer).
        counts = []
        for r in READINGS:
            theirs = dict(
                zip(comparisons[rival].seeds, comparisons[rival].ratio[r]["demos"].low, strict=True)
            )
            mine = c.ratio[r]["demos"].low
            pairs = [(v, theirs[s]) for s, v in zip(c.seeds, mine, strict=True) if s in theirs]
            counts.append((sum(v is not None and (t is None or v < t) for v, t in pairs), pairs))
        (fewer, pairs), (fewer_trained, _) = counts
        shown = "; ".join(
            f"{'-' if r is None else f'{r:.3f}x'} vs {'not reached' if t is None else f'{t:.3f}x'}"
            for r, t in pairs
        )
        verdict = "met" if pairs and fewer == len(pairs) else "missed"
        lines.append(
            f"- ... with fewer demonstrations than the best initial-state arm ({labels.get(rival, rival)}): "
            f"{verdict}, fewer on {fewer} of the {len(pairs)} seeds both ran (of Uniform's added demos, per "
            f"seed: {shown}); at trained policies fewer on {fewer_trained} of {len(pairs)}."
        )
    lines.append(five_points_line("expert frames", c.frames_diff))
    return lines
