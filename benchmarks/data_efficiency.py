"""AdaDemo's data efficiency against Uniform and the ablations on MetaWorld (paper Table I, Fig. 1, Table III).

    python benchmarks/data_efficiency.py --seeds 0 1 [--out ~/adademo-bench] [--aggregate_only]

Per seed: a shared round 0 (`recipes/adademo.yaml` with --rounds=0: 10 scripted demos per task, ACT, fixed
evaluation set of 50 initial states per task), then the four arms continue from copies of it, each for 3 rounds:
adademo (A+B+C), ablation_ab (A+B), ablation_a (A), and uniform, whose per-round N_i is AdaDemo's average number of
new demos per task in that round rounded up (the paper gives Uniform an equal or slightly larger budget). Every
run is an `adademo-run` folder, so the whole benchmark resumes after an interruption (rerun the same command).
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
}
LABELS = {"adademo": "AdaDemo (A+B+C)", "ablation_ab": "A+B", "ablation_a": "A", "uniform": "Uniform"}


def adademo_run(recipe: str, run_dir: Path, seed: int, *extra: str) -> None:
    cmd = [str(BIN / "adademo-run"), f"--config_path={ROOT / 'recipes' / recipe}", f"--run_dir={run_dir}",
           f"--seed={seed}", f"--train.seed={1000 + seed}", *extra]
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

    cfg = parse_config(RunConfig, [f"--config_path={ROOT / 'recipes' / recipe}", f"--run_dir={arm_dir}", *extra])
    state["settings"].update({
        "strategy": cfg.strategy, "sampler": cfg.train.sampler, "rounds": cfg.rounds,
        "target_successes": cfg.target_successes, "max_demos_per_task": cfg.max_demos_per_task,
        "demos_per_task": cfg.demos_per_task, "min_task_weight": cfg.train.min_task_weight,
        "train_mode": cfg.train.mode,
    })
    state["done"] = {k: v for k, v in state["done"].items() if k in ("collect", "train-0", "eval-0")}
    (tmp / "run_state.json").write_text(json.dumps(state, indent=2))
    tmp.rename(arm_dir)


def uniform_budget(adademo_dir: Path, rounds: int) -> list[int]:
    from adademo_lerobot.ledger import read_ledger

    ledger = pd.DataFrame(read_ledger(adademo_dir / "dataset"))
    return [math.ceil(ledger[ledger["round"] == r].demos_added.mean()) for r in range(1, rounds + 1)]


def run_seed(out: Path, seed: int) -> None:
    base = out / f"seed{seed}" / "base"
    adademo_run("adademo.yaml", base, seed, "--rounds=0")
    for arm in ("adademo", "ablation_ab", "ablation_a", "uniform"):
        arm_dir = out / f"seed{seed}" / arm
        extra = []
        if arm == "uniform":
            budget = uniform_budget(out / f"seed{seed}" / "adademo", 3)
            extra.append(f"--demos_per_task=[{','.join(map(str, budget))}]")
        branch_from_base(base, arm_dir, ARMS[arm], extra)
        adademo_run(ARMS[arm], arm_dir, seed, *extra)


def aggregate(out: Path, seeds: list[int]) -> None:
    from adademo_lerobot.report import load_run

    runs = {(arm, s): load_run(out / f"seed{s}" / arm) for arm in ARMS for s in seeds
            if (out / f"seed{s}" / arm / "eval").exists()}
    complete = [s for s in seeds if all((arm, s) in runs and len(runs[(arm, s)].success.columns) == 4 for arm in ARMS)]
    if not complete:
        sys.exit("no seed has all four arms through round 3 yet")
    tasks = runs[("adademo", complete[0])].tasks
    rows, curves = [], {}
    for arm in ARMS:
        sr = np.stack([runs[(arm, s)].success.loc[tasks].to_numpy() for s in complete])  # seed x task x round
        demos = np.stack([runs[(arm, s)].demos.loc[tasks].to_numpy() for s in complete])
        curves[arm] = (demos.mean(axis=(0, 1)), sr.mean(axis=1).mean(axis=0), sr.mean(axis=1).std(axis=0))
        for t, task in enumerate(tasks + ["average"]):
            vals = sr[:, t] if t < len(tasks) else sr.mean(axis=1)
            d = demos[:, t] if t < len(tasks) else demos.mean(axis=1)
            rows.append({"arm": arm, "task": task,
                         **{f"r{r}": f"{100 * vals[:, r].mean():.0f} ± {100 * vals[:, r].std():.0f} ({d[:, r].mean():.0f})"
                            for r in range(4)}})
    # Headline 1: demos AdaDemo needs to reach Uniform's final average SR (interpolated on AdaDemo's curve).
    ux, uy, _ = curves["uniform"]
    ax_, ay, _ = curves["adademo"]
    target, reached = uy[-1], None
    for k in range(1, len(ax_)):
        if ay[k] >= target:
            lo = ay[k - 1]
            frac = 1.0 if ay[k] == lo else (target - lo) / (ay[k] - lo)
            reached = ax_[k - 1] + max(0.0, frac) * (ax_[k] - ax_[k - 1]) if lo < target else ax_[k - 1]
            break
    if ay[0] >= target:
        reached = ax_[0]
    # Headline 2: SR difference at (about) equal budget after round 3.
    diff = 100 * (ay[-1] - uy[-1])
    plot(curves, RESULTS / "data_efficiency.png")
    table = pd.DataFrame(rows)
    lines = [
        "# Data efficiency on MetaWorld: AdaDemo vs Uniform and the ablations",
        "",
        f"Command: `python benchmarks/data_efficiency.py --seeds {' '.join(map(str, seeds))}`; {machine_line()}.",
        f"Seeds with all arms complete: {complete}. Tasks: {', '.join(tasks)}. Recipes: `recipes/{{adademo,ablation_ab,"
        "ablation_a,uniform}.yaml` (small state ACT, 10 initial demos per task, 3 rounds, E = 5/10/20, CAP = 20/40/80,",
        "fine-tuning 800 steps per round), evaluated on the same 50 fixed initial states per task every round.",
        "Uniform's N_i = AdaDemo's mean new demos per task in round i, rounded up.",
        "",
        "Success rate % (mean ± std over seeds) and, in brackets, demos per task after each round:",
        "",
        "| arm | task | " + " | ".join(f"round {r}" for r in range(4)) + " |",
        "| --- | --- |" + " --- |" * 4,
        *[f"| {LABELS[row.arm]} | {row.task} | " + " | ".join(getattr(row, f"r{r}") for r in range(4)) + " |"
          for row in table.itertuples()],
        "",
        "![success vs demos](data_efficiency.png)",
        "",
        f"- Uniform's final average SR: {100 * uy[-1]:.1f}% with {ux[-1]:.1f} demos per task.",
        (f"- AdaDemo reaches it with {reached:.1f} demos per task: **{reached / ux[-1]:.2f}x** Uniform's demos "
         "(goal <= 1/3)." if reached is not None else
         f"- AdaDemo does not reach Uniform's final average SR within {ax_[-1]:.1f} demos per task (goal: <= 1/3 of Uniform's)."),
        f"- After round 3: AdaDemo {100 * ay[-1]:.1f}% with {ax_[-1]:.1f} demos per task vs Uniform {100 * uy[-1]:.1f}% with "
        f"{ux[-1]:.1f}: **{diff:+.1f} points** (goal >= +5).",
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
    args = parser.parse_args()
    start = time.time()
    if not args.aggregate_only:
        for seed in args.seeds:
            run_seed(args.out, seed)
    aggregate(args.out, args.seeds)
    print(f"total {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
