"""AdaDemo's data efficiency against Uniform and the ablations on MetaWorld (paper Table I, Fig. 1, Table III).

    python benchmarks/data_efficiency.py --seeds 0 1 [--out ~/adademo-bench] [--aggregate_only] [--uniform_3x]

Per seed: a shared round 0 (`recipes/adademo.yaml` with --rounds=0: 10 scripted demos per task, ACT, fixed
evaluation set of 50 initial states per task), then the four arms continue from copies of it, each for 3 rounds:
adademo (A+B+C), ablation_ab (A+B), ablation_a (A), and uniform, whose per-round N_i is AdaDemo's average number of
new demos per task in that round rounded up (the paper gives Uniform an equal or slightly larger budget). Every
run is an `adademo-run` folder, so the whole benchmark resumes after an interruption (rerun the same command).
With --uniform_3x a fifth arm gives Uniform three times AdaDemo's per-round budget: the paper's Fig. 1 compares
against a Uniform that kept collecting until it plateaued, which an equal budget cannot show.
Round 0 needs no sampler choice: with equal demos per task, trajectory- and task-uniform sampling coincide.

Writes benchmarks/results/data_efficiency.md and data_efficiency.png.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from _common import BIN, RESULTS, ROOT, machine_line

ARMS = {  # arm -> recipe (strategy + sampler)
    "adademo": "adademo.yaml",
    "ablation_ab": "ablation_ab.yaml",
    "ablation_a": "ablation_a.yaml",
    "uniform": "uniform.yaml",
    "uniform_3x": "uniform.yaml",  # optional (--uniform_3x)
}
MAIN_ARMS = ["adademo", "ablation_ab", "ablation_a", "uniform"]
LABELS = {
    "adademo": "AdaDemo (A+B+C)",
    "ablation_ab": "A+B",
    "ablation_a": "A",
    "uniform": "Uniform",
    "uniform_3x": "Uniform, 3x budget",
}
BUDGET_FACTOR = {"uniform": 1, "uniform_3x": 3}  # x AdaDemo's mean new demos per task, per round


TORCH_THREADS: list[str] = []  # --torch_threads: set when two drivers share the cores


def adademo_run(recipe: str, run_dir: Path, seed: int, *extra: str) -> None:
    cmd = [
        str(BIN / "adademo-run"),
        f"--config_path={ROOT / 'recipes' / recipe}",
        f"--run_dir={run_dir}",
        f"--seed={seed}",
        f"--train.seed={1000 + seed}",
        *TORCH_THREADS,
        *extra,
    ]
    print("$", " ".join(cmd), flush=True)
    log = run_dir.parent / f"{run_dir.name}.log"
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as f:
        if subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT).returncode != 0:
            sys.exit(f"{run_dir} failed: see {log}")


def branch_from_base(base: Path, arm_dir: Path, recipe: str, extra: list[str]) -> None:
    """Start an arm from a copy of the shared round 0 (dataset, checkpoint, evaluation)."""
    if arm_dir.exists():
        return
    tmp = arm_dir.with_name(arm_dir.name + ".copying")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(base, tmp, ignore=shutil.ignore_patterns("report"))
    state = json.loads((tmp / "run_state.json").read_text())
    from adademo_lerobot.cli import parse_config
    from adademo_lerobot.run import RunConfig

    cfg = parse_config(
        RunConfig, [f"--config_path={ROOT / 'recipes' / recipe}", f"--run_dir={arm_dir}", *extra]
    )
    state["settings"].update(
        {
            "strategy": cfg.strategy,
            "sampler": cfg.train.sampler,
            "rounds": cfg.rounds,
            "target_successes": cfg.target_successes,
            "max_demos_per_task": cfg.max_demos_per_task,
            "demos_per_task": cfg.demos_per_task,
            "min_task_weight": cfg.train.min_task_weight,
            "train_mode": cfg.train.mode,
        }
    )
    state["done"] = {k: v for k, v in state["done"].items() if k in ("collect", "train-0", "eval-0")}
    (tmp / "run_state.json").write_text(json.dumps(state, indent=2))
    tmp.rename(arm_dir)


def uniform_budget(adademo_dir: Path, rounds: int, factor: int) -> list[int]:
    from adademo_lerobot.ledger import read_ledger

    ledger = pd.DataFrame(read_ledger(adademo_dir / "dataset"))
    if ledger.empty or not set(range(1, rounds + 1)) <= set(ledger["round"]):
        sys.exit(
            f"{adademo_dir} has not finished its {rounds} rounds: Uniform's budget follows AdaDemo's (run it first)"
        )
    return [math.ceil(factor * ledger[ledger["round"] == r].demos_added.mean()) for r in range(1, rounds + 1)]


def run_seed(out: Path, seed: int, arms: list[str]) -> None:
    base = out / f"seed{seed}" / "base"
    adademo_run("adademo.yaml", base, seed, "--rounds=0")
    for arm in arms:
        arm_dir = out / f"seed{seed}" / arm
        extra = []
        if arm in BUDGET_FACTOR:
            budget = uniform_budget(out / f"seed{seed}" / "adademo", 3, BUDGET_FACTOR[arm])
            extra.append(f"--demos_per_task=[{','.join(map(str, budget))}]")
        branch_from_base(base, arm_dir, ARMS[arm], extra)
        adademo_run(ARMS[arm], arm_dir, seed, *extra)


def demos_to_reach(x: np.ndarray, y: np.ndarray, target: float) -> float | None:
    """Average demos per task at which the curve (x, y) first reaches `target`, interpolated linearly."""
    if y[0] >= target:
        return float(x[0])
    for k in range(1, len(x)):
        if y[k] >= target:
            frac = (target - y[k - 1]) / (y[k] - y[k - 1])
            return float(x[k - 1] + frac * (x[k] - x[k - 1]))
    return None


def aggregate(out: Path, seeds: list[int]) -> None:
    from adademo_lerobot.report import load_run

    runs = {
        (arm, s): load_run(out / f"seed{s}" / arm)
        for arm in ARMS
        for s in seeds
        if (out / f"seed{s}" / arm / "eval").exists()
    }
    done = {
        arm: [s for s in seeds if (arm, s) in runs and len(runs[(arm, s)].success.columns) == 4]
        for arm in ARMS
    }
    complete = [s for s in seeds if all(s in done[arm] for arm in MAIN_ARMS)]
    if not complete:
        sys.exit("no seed has all four arms through round 3 yet")
    arms = MAIN_ARMS + [arm for arm in ARMS if arm not in MAIN_ARMS and done[arm]]
    arm_seeds = {arm: complete if arm in MAIN_ARMS else done[arm] for arm in arms}
    tasks = runs[("adademo", complete[0])].tasks
    rows, curves = [], {}
    for arm in arms:
        sr = np.stack(
            [runs[(arm, s)].success.loc[tasks].to_numpy() for s in arm_seeds[arm]]
        )  # seed x task x round
        demos = np.stack([runs[(arm, s)].demos.loc[tasks].to_numpy() for s in arm_seeds[arm]])
        curves[arm] = (demos.mean(axis=(0, 1)), sr.mean(axis=1).mean(axis=0), sr.mean(axis=1).std(axis=0))
        for t, task in enumerate(tasks + ["average"]):
            vals = sr[:, t] if t < len(tasks) else sr.mean(axis=1)
            d = demos[:, t] if t < len(tasks) else demos.mean(axis=1)
            rows.append(
                {
                    "arm": arm,
                    "task": task,
                    **{
                        f"r{r}": f"{100 * vals[:, r].mean():.0f} ± {100 * vals[:, r].std():.0f} ({d[:, r].mean():.0f})"
                        for r in range(4)
                    },
                }
            )
    ax_, ay, _ = curves["adademo"]
    headlines = []
    # Headline 1: demos AdaDemo needs to reach a Uniform arm's final average SR (interpolated on AdaDemo's curve).
    for arm in [a for a in arms if a in BUDGET_FACTOR]:
        ux, uy, _ = curves[arm]
        reached = demos_to_reach(ax_, ay, uy[-1])
        headlines.append(
            f"- {LABELS[arm]} (seeds {arm_seeds[arm]}): final average SR {100 * uy[-1]:.1f}% with "
            f"{ux[-1]:.1f} demos per task. "
            + (
                f"AdaDemo reaches it with {reached:.1f} demos per task: **{reached / ux[-1]:.2f}x** Uniform's demos "
                f"(goal <= 1/3; the shared round 0 alone is {ax_[0] / ux[-1]:.2f}x)."
                if reached is not None
                else f"AdaDemo does not reach it within its {ax_[-1]:.1f} demos per task (goal: <= 1/3 of Uniform's)."
            )
        )
    # Headline 2: SR difference at (about) equal budget after round 3.
    ux, uy, _ = curves["uniform"]
    diff = 100 * (ay[-1] - uy[-1])
    headlines.append(
        f"- After round 3 at about equal budget: AdaDemo {100 * ay[-1]:.1f}% with {ax_[-1]:.1f} demos per "
        f"task vs Uniform {100 * uy[-1]:.1f}% with {ux[-1]:.1f}: **{diff:+.1f} points** (goal >= +5)."
    )
    plot(curves, RESULTS / "data_efficiency.png")
    table = pd.DataFrame(rows)
    flags = " --uniform_3x" if "uniform_3x" in arms else ""
    lines = [
        "# Data efficiency on MetaWorld: AdaDemo vs Uniform and the ablations",
        "",
        f"Command: `python benchmarks/data_efficiency.py --seeds {' '.join(map(str, seeds))}{flags}`; {machine_line()}.",
        f"Seeds with the four main arms complete: {complete}. Tasks: {', '.join(tasks)}. Recipes: `recipes/{{adademo,"
        "ablation_ab,ablation_a,uniform}.yaml` (small state ACT, 10 initial demos per task, 3 rounds, E = 5/10/20,",
        "CAP = 20/40/80, fine-tuning 800 steps per round), evaluated on the same 50 fixed initial states per task every",
        "round. Uniform's N_i = AdaDemo's mean new demos per task in round i, rounded up"
        + (" (x3 for the 3x arm)." if "uniform_3x" in arms else "."),
        "",
        "Success rate % (mean ± std over seeds) and, in brackets, demos per task after each round:",
        "",
        "| arm | task | " + " | ".join(f"round {r}" for r in range(4)) + " |",
        "| --- | --- |" + " --- |" * 4,
        *[
            f"| {LABELS[row.arm]} | {row.task} | "
            + " | ".join(getattr(row, f"r{r}") for r in range(4))
            + " |"
            for row in table.itertuples()
        ],
        "",
        "![success vs demos](data_efficiency.png)",
        "",
        *headlines,
    ]
    (RESULTS / "data_efficiency.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for arm, (x, y, e) in curves.items():
        ax.errorbar(x, 100 * y, yerr=100 * e, marker="o", capsize=3, label=LABELS[arm])
    ax.set_xlabel("average demos per task")
    ax.set_ylabel("average success rate (%)")
    ax.set_title("MetaWorld (6 tasks): success vs demonstrations")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--out", type=Path, default=Path.home() / "adademo-bench")
    parser.add_argument("--aggregate_only", action="store_true")
    parser.add_argument("--uniform_3x", action="store_true", help="also run Uniform with 3x AdaDemo's budget")
    parser.add_argument(
        "--arms",
        nargs="+",
        choices=list(ARMS),
        help="run only these arms (e.g. two drivers on disjoint arms; uniform arms need adademo's ledger)",
    )
    parser.add_argument(
        "--torch_threads",
        type=int,
        help="torch threads per run (default: the recipe's 2); use 1 when two drivers share 2 cores",
    )
    args = parser.parse_args()
    if args.torch_threads:
        TORCH_THREADS.append(f"--train.torch_threads={args.torch_threads}")
    start = time.time()
    if not args.aggregate_only:
        arms = args.arms or MAIN_ARMS + (["uniform_3x"] if args.uniform_3x else [])
        for seed in args.seeds:
            run_seed(args.out, seed, arms)
    if not args.arms:  # a partial driver leaves the tables to a full run or --aggregate_only
        aggregate(args.out, args.seeds)
    print(f"total {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
