"""Data efficiency on MetaWorld: Uniform against AdaDemo (the paper's), AdaDemo with the tempered sampler and the
budgeted strategy, at equal demonstrations per round, with the noise of the measurement measured first.

    python benchmarks/data_efficiency.py select              # round-0 table of candidate tasks -> the task set
    python benchmarks/data_efficiency.py noise               # noise floor: one round trained twice, two seeds
    python benchmarks/data_efficiency.py noise --arms budgeted_tempered --lr_schedule cosine   # with another schedule
    python benchmarks/data_efficiency.py arms --seeds 0 1 2 [--arms uniform adademo ...] [--torch_threads 1]
    python benchmarks/data_efficiency.py reread --from_out OLD --seeds 1 --arms uniform   # read again (below)
    python benchmarks/data_efficiency.py export              # summaries of arms an older driver finished
    python benchmarks/data_efficiency.py report --seeds 0 1 2 [--arms ...]   # the arms to report (and Uniform)

Every run is an `adademo-run` folder under --out (default ~/adademo-bench), so every phase resumes after an
interruption (rerun the same command). `arms` started twice with the same flags (give each `--torch_threads 1`)
shares the runs between the two drivers: each takes the next run no other driver holds, so two cores work on one
table without splitting it by hand. A finished arm is summarised into
`benchmarks/results/data_efficiency/seed<S>-<arm>.json` (success and demos per task and round, its ledger, its
settings, the machine), and `arms` does not run an arm with a summary again; `select` and `noise` write
their tables there too: commit them. `report` reads only that folder, so seeds run in different sessions or on
different machines combine, and anyone can regenerate the results from the committed figures.

The recipe is `recipes/budgeted.yaml`: its tasks, budgets, CAPs, model and training regime are the ones this
benchmark chose (select, noise); the arms differ only in strategy and sampler:

    uniform            --strategy.type=uniform   (the budget split evenly: exactly B_i demos per round)
    adademo            --strategy.type=adademo   (the paper's: E picked by --budget, at most B_i), trajectory sampler
    adademo_tempered   --strategy.type=adademo   + --train.sampler=tempered --train.sampler_alpha=0.5
    budgeted_tempered  --strategy.type=budgeted  (exactly B_i) + tempered sampler
    budgeted           --strategy.type=budgeted  + trajectory sampler (which sampler suits the budget strategy)
    task_only          --strategy.type=task_only with the recipe's budget: budgeted's evaluations and split, each
                       failure answered from a fresh state (ablation A; budgeted minus it is principle B alone)
    costed, costed_knn budgeted + --strategy.rollout_cost=1 (rollouts paid from the budget), random or k-NN states
    costed_w5          costed with --strategy.failure_worth=5 (evaluates longer before it closes a task)
    costed_probe       costed with --strategy.probe_unsure=true (a task is probed before it gets nothing)
    costed_split       costed_probe + --strategy.split_episodes=true (the round's budget, rollouts included, split
                       across the tasks by expected failure rate instead of evaluating the weakest task first)
    costed_split_o9    costed_split + --strategy.optimism=0.9 (five straight successes close a task, not three)
    costed_split_knn   costed_split + --strategy.rank_states=knn (rollouts and fresh-state demonstrations at the
                       candidate states a k-NN vote over every outcome so far predicts likeliest to fail)
    costed_split_knn_fresh  costed_split + --strategy.rank_states=knn_fresh (only the fresh-state demonstrations
                       ranked; evaluations at random states keep the posterior unbiased)
    costed_split_takeover  costed_split + --demo_start=takeover (each failed rollout corrected from where it
                       went wrong; the rollout and its correction are one scene reset)
    costed_probe_keep  costed_probe + --keep_successes=true --train.autonomous_weight=1 (its successful
                       rollouts kept as data, each drawn as a demonstration)

`--cpu_isa avx2` (the default) pins the runs' numeric kernels to AVX2 and MKL's to its reproducible Intel AVX2
branch (`MKL_CBWR=AVX2`), on an AMD CPU through a preloaded shim that tells MKL it runs on an Intel one
(`mkl_intel_path.c`): an AVX-512 AMD EPYC then trains the same weights as an Intel Xeon, digest for digest. Without the
shim (`avx2_own_mkl`, what AMD machines ran before 2026-12-08: the AMD-only folders' runs) AMD and Intel CPUs train
other policies from the same data; `native`: the machine's own kernels. The summary's machine line says which;
`kernel_reproducibility.py` says in a few minutes whether a machine trains the same weights as the ones that ran
the committed summaries, and `arms` compares a rebuilt round 0 with the seed's summaries before any arm runs.

`--test_states per_seed` evaluates each seed on its own fixed states (--eval.seed=100+seed), so that the intervals
over seeds include the sampling of the test states; `shared` (the default, and every folder written before it)
evaluates every seed on eval seed 100's states.

`reread` copies each seed's base and policy-free arms (Uniform) from another --out into this one and evaluates
them again under --recipe, whose policy may differ from theirs only in how a trained policy acts (ACT's
n_action_steps and temporal ensembling: the same weights either way), so a recipe that changes the readout reuses
their collection and training.

Per seed all arms branch from one shared round 0 (dataset, policy, evaluation), train each round from scratch with
the same training seed, and are evaluated on the same fixed initial states (50 per task): comparisons are paired.
`report` writes benchmarks/results/data_efficiency.md and data_efficiency.png.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from _common import AVX2_KERNELS, BIN, RESULTS, ROOT, avx2_kernels, machine_line

from adademo_lerobot.core.tables import table
from adademo_lerobot.evaluation.policy import READOUT_FIELDS

RECIPE = ROOT / "recipes" / "budgeted.yaml"
SUMMARIES = RESULTS / "data_efficiency"  # committed: what `report` is built from
CANDIDATES = (
    "reach-v3,push-v3,pick-place-v3,door-open-v3,drawer-open-v3,drawer-close-v3,button-press-topdown-v3,"
    "peg-insert-side-v3,window-open-v3,window-close-v3,button-press-v3,coffee-button-v3,plate-slide-v3,"
    "handle-press-v3,faucet-open-v3,sweep-into-v3"
)
# Corrections: one attempt from the takeover state, then (if the expert fails there) a demonstration from the
# failed episode's initial state; `_retry3` is the first protocol (3 attempts there, nothing if they fail).
TAKEOVER = [
    "--demo_start=takeover",
    "--takeover.backoff=10",
    "--takeover.attempts=1",
    "--takeover.fallback=initial",
]
RETRY3 = ["--takeover.attempts=3", "--takeover.fallback=none"]
DISAGREEMENT = ["--takeover.rule=disagreement", "--takeover.threshold=1.5", "--takeover.consecutive=5"]
BACKOFF = ["--takeover.rule=backoff", "--takeover.stall_tolerance=0.01"]
ALL_ARMS = {
    "uniform": ["--strategy.type=uniform", "--train.sampler=trajectory"],
    "adademo": ["--strategy.type=adademo", "--train.sampler=trajectory"],
    # AdaDemo giving a task whose first demonstrations disagree (imitability below 0.1) only an even share of the
    # round (the Adroit table's first recipe: 154 of AdaDemo's 185 demonstrations went to two such tasks).
    "adademo_limited": [
        "--strategy.type=adademo",
        "--train.sampler=trajectory",
        "--strategy.limit_disagreeing=true",
    ],
    "adademo_tempered": ["--strategy.type=adademo", "--train.sampler=tempered", "--train.sampler_alpha=0.5"],
    "budgeted_tempered": [
        "--strategy.type=budgeted",
        "--train.sampler=tempered",
        "--train.sampler_alpha=0.5",
    ],
    "budgeted": ["--strategy.type=budgeted", "--train.sampler=trajectory"],
    # Ablation A at the same budget and with the same evaluations as budgeted (the recipe's budget, CAP, decay):
    # every failure is answered from a fresh state instead; budgeted minus this is principle B alone.
    "task_only": ["--strategy.type=task_only", "--train.sampler=trajectory"],
    # Rollouts paid from the budget at the cost of a demonstration (a robot's scene reset each): B_i episodes per
    # round, Uniform's; evaluation only where a found failure is worth its rollouts (W = 3), random or k-NN states.
    "costed": ["--strategy.type=budgeted", "--train.sampler=trajectory", "--strategy.rollout_cost=1"],
    "costed_knn": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.rank_states=knn",
    ],
    # W = 5: a failure worth more, so evaluation pays down to p = 1/4 (closes after ~5 straight successes, not 2)
    # and fresh demonstrations down to p = 1/5: on seed 0, W = 3 closed peg-insert (54 %) after two lucky successes.
    "costed_w5": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.failure_worth=5",
    ],
    "costed_probe": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
    ],
    # costed_probe with the round's budget, rollouts included, split across the tasks by expected failure rate
    # instead of evaluating the likeliest-failing task first (which gave most of a round to the weakest task).
    "costed_split": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--strategy.split_episodes=true",
    ],
    # costed_split keeping a task open until five straight successes, not three (MT10 seed 2: reach-v3 at 62 %
    # succeeded three times in round 1, was closed for round 2 and ended 20 points under Uniform).
    "costed_split_o9": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--strategy.split_episodes=true",
        "--strategy.optimism=0.9",
    ],
    # costed_split with failure prediction: evaluated states and fresh-state demonstrations are the candidates a k-NN
    # vote predicts likeliest to fail (issue 35's "demonstrate at the predicted failures with no rollout").
    "costed_split_knn": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--strategy.split_episodes=true",
        "--strategy.rank_states=knn",
    ],
    # The same ranking for the fresh-state demonstrations only: the evaluated states stay random, so the posterior
    # that splits the budget is not inflated by ranked (likelier-failing) states.
    "costed_split_knn_fresh": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--strategy.split_episodes=true",
        "--strategy.rank_states=knn_fresh",
    ],
    # costed_split where each failed rollout ends in a correction from where it went wrong, in the same scene: the
    # rollout and the correction are one episode (issue 35's "no wasted rollout"), so a found failure costs one reset,
    # not two; the expert's one attempt there, then (if it fails) a demonstration from the initial state.
    "costed_split_takeover": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--strategy.split_episodes=true",
        *TAKEOVER,
        *DISAGREEMENT,
    ],
    # costed_probe keeping its successful rollouts as data (no episode it did not run), each drawn as a
    # demonstration of its task: it runs ~7 rollouts per task in three rounds (benchmarks/results/mt10_cost.md), so
    # a strong task's few kept successes cannot take the weak tasks' share of training.
    "costed_probe_keep": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true",
        "--keep_successes=true",
        "--train.autonomous_weight=1",
    ],
    # Corrections from the point of failure (--demo_start=takeover), with either rule (the default chosen here).
    "budgeted_takeover": ["--strategy.type=budgeted", "--train.sampler=trajectory", *TAKEOVER, *DISAGREEMENT],
    "adademo_takeover": ["--strategy.type=adademo", "--train.sampler=trajectory", *TAKEOVER, *DISAGREEMENT],
    "budgeted_takeover_backoff": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        *TAKEOVER,
        *BACKOFF,
    ],
    "budgeted_takeover_retry3": [
        "--strategy.type=budgeted",
        "--train.sampler=trajectory",
        *TAKEOVER,
        *DISAGREEMENT,
        *RETRY3,
    ],
}
LABELS = {
    "uniform": "Uniform",
    "adademo": "AdaDemo (paper: E from the budget, trajectory sampler)",
    "adademo_limited": "AdaDemo, disagreeing tasks limited to an even share",
    "adademo_tempered": "AdaDemo + tempered sampler (alpha 0.5)",
    "budgeted_tempered": "Budgeted + tempered sampler (alpha 0.5)",
    "budgeted": "Budgeted + trajectory sampler",
    "task_only": "Ablation A: budgeted's split from fresh states",
    "costed": "Budgeted paying for rollouts (cost 1, W = 3)",
    "costed_knn": "Budgeted paying for rollouts (cost 1, W = 3), k-NN states",
    "costed_w5": "Budgeted paying for rollouts (cost 1, W = 5)",
    "costed_probe": "Budgeted paying for rollouts (cost 1, W = 3), probing unsure tasks",
    "costed_probe_keep": "costed_probe keeping its successful rollouts (each as a demonstration)",
    "costed_split": "costed_probe splitting the round's episodes by expected failure",
    "costed_split_o9": "costed_split closing a task after five straight successes (optimism 0.9)",
    "costed_split_knn": "costed_split at the states a k-NN vote predicts likeliest to fail",
    "costed_split_knn_fresh": "costed_split demonstrating at the fresh states a k-NN vote predicts likeliest to fail",
    "costed_split_takeover": "costed_split correcting each failed rollout where it went wrong (one episode)",
    "budgeted_takeover": "Budgeted + takeover corrections (disagreement)",
    "adademo_takeover": "AdaDemo + takeover corrections (disagreement)",
    "budgeted_takeover_backoff": "Budgeted + takeover corrections (backoff)",
    "budgeted_takeover_retry3": "Budgeted + takeover corrections (disagreement, 3 attempts there, no fallback)",
}
TORCH_THREADS: list[str] = []
# --base_flags: adademo-run flags for building a seed's round-0 base only (its collection and training may use both
# cores before the arms run side by side, one core each); they come last, so they win over --torch_threads.
BASE_FLAGS: list[str] = []
# --test_states per_seed: each seed is evaluated on its own fixed initial states (--eval.seed=100+seed), so the
# intervals over seeds include the sampling of the test states; `shared`: every seed on eval seed 100's (the
# folders written before this option).
TEST_STATES = ["shared"]
# A seed's shared round 0, which every arm starts from a copy of.
BASE_STAGES = ("collect", "train-0", "eval-0")


def adademo_run(run_dir: Path, *flags: str) -> None:
    cmd = [
        str(BIN / "adademo-run"),
        f"--config_path={RECIPE}",
        f"--run_dir={run_dir}",
        *TORCH_THREADS,
        *flags,
    ]
    print("$", " ".join(cmd), flush=True)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(run_dir.parent / f"{run_dir.name}.log", "a") as log:
        if subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode != 0:
            sys.exit(f"{run_dir} failed: see {run_dir.parent / f'{run_dir.name}.log'}")


def seed_flags(seed: int) -> list[str]:
    flags = [f"--seed={seed}", f"--train.seed={1000 + seed}"]
    return flags + ([f"--eval.seed={100 + seed}"] if TEST_STATES[0] == "per_seed" else [])


def eval_summary(run_dir: Path, round_index: int) -> Path:
    """Where adademo-run writes a round's evaluation (its last stage: written, the round is done)."""
    return run_dir / "eval" / f"round-{round_index:03d}" / "eval_summary.json"


def finished(run_dir: Path) -> bool:
    """Every round of the run evaluated: its recipe's rounds (3 where its run state does not say)."""
    state = run_dir / "run_state.json"
    rounds = json.loads(state.read_text())["settings"].get("rounds", 3) if state.exists() else 3
    return eval_summary(run_dir, rounds).exists()


def base_done(base: Path) -> bool:
    return eval_summary(base, 0).exists()


def build_base(base: Path, seed: int) -> None:
    """The seed's shared round 0 (dataset, policy, evaluation), which every arm starts from a copy of."""
    adademo_run(base, "--rounds=0", *seed_flags(seed), *BASE_FLAGS)


def ensure_base(out: Path, seed: int) -> Path:
    """The seed's base, built by whichever driver gets there first (the other waits for it)."""
    base = out / f"seed{seed}" / "base"
    with claimed(base, wait=True):
        if not base_done(base):
            build_base(base, seed)
    return base


def pending_runs(out: Path, seeds: list[int], arms: list[str]) -> list[Path]:
    """The runs `arms` still has to do, in the order it does them: arm by arm over the seeds (so the first arms
    have every seed before the next starts, which is what a report pairs), a seed's shared round 0 (its base)
    in place of its arms until that is done. An arm with a summary is done, wherever it ran."""
    pending: list[Path] = []
    for arm in arms:
        for seed in seeds:
            if (SUMMARIES / f"seed{seed}-{arm}.json").exists():
                continue
            base = out / f"seed{seed}" / "base"
            run_dir = out / f"seed{seed}" / arm if base_done(base) else base
            if not finished(run_dir) and run_dir not in pending:
                pending.append(run_dir)
    return pending


@contextmanager
def claimed(run_dir: Path, wait: bool = False) -> Iterator[bool]:
    """Whether this driver holds `run_dir` (an advisory lock on its sibling `<name>.lock`, which the kernel
    releases however the driver ends); without `wait`, False at once when another driver holds it."""
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(run_dir.parent / f"{run_dir.name}.lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
        else:
            yield True


def cpu_of(machine: str) -> str:
    """The CPU a summary's (or this machine's) machine line names."""
    found = re.search(r"machine: (.*?), \d+ CPU cores", machine)
    return found.group(1) if found else machine


def mkl_kernels(cpu: str) -> str:
    """Which of MKL's kernels a machine line's CPU ran: Intel's on an Intel CPU or through the shim, else its own."""
    return "Intel" if "Intel" in cpu or "MKL's Intel path" in cpu else "AMD" if "AMD" in cpu else cpu


def check_seed_pairs_here(seed: int, base: Path | None = None) -> None:
    """Refuse to run seed `seed` here if its arms would not pair with the ones already summarised for it: MKL's
    AMD kernels train other policies than its Intel ones from the same demonstrations (kernel_reproducibility.md),
    and two machines may differ otherwise, which the round 0 of `base` shows once it is built. An arm from another
    round 0 would be left out of the report, hours later."""
    here = cpu_of(machine_line())
    for path in sorted(SUMMARIES.glob(f"seed{seed}-*.json")):
        summary = json.loads(path.read_text())
        there = cpu_of(summary["machine"])
        where = f"{SUMMARIES.name}/{path.name} ran on {there}"
        if mkl_kernels(there) != mkl_kernels(here):
            sys.exit(
                f"error: {where} and this machine is {here}: MKL's {mkl_kernels(here)} kernels train other "
                f"policies than its {mkl_kernels(there)} ones from the same demonstrations, so seed {seed}'s arms "
                f"run here would not pair with it; run seed {seed} with the kernels it ran with "
                "(--cpu_isa), or a new seed here"
            )
        if base is None:
            continue
        theirs = {task: rates[0] for task, rates in summary["success"].items()}
        ours = {task: rate for task, rate in eval_table(base, 0).items() if task in theirs}  # not "average"
        if ours != theirs:
            sys.exit(
                f"error: seed {seed}'s round 0 built here ({100 * sum(ours.values()) / len(theirs):.1f} %) differs "
                f"from the one {where} started from ({100 * sum(theirs.values()) / len(theirs):.1f} %): this "
                f"machine trains other policies, so its arms would not pair; run seed {seed} on a machine like "
                f"that one, or a new seed here ({base} is kept)"
            )


def branch_from_base(base: Path, arm_dir: Path, flags: list[str]) -> None:
    """An arm starts from a copy of the seed's shared round 0 (dataset, checkpoint, evaluation)."""
    if arm_dir.exists():
        return
    from adademo_lerobot.loop.cli import parse_config
    from adademo_lerobot.loop.run import RunConfig, run_settings

    tmp = arm_dir.with_name(arm_dir.name + ".copying")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(base, tmp, ignore=shutil.ignore_patterns("report"))
    state = json.loads((tmp / "run_state.json").read_text())
    cfg = parse_config(RunConfig, [f"--config_path={RECIPE}", f"--run_dir={arm_dir}", *flags])
    state["settings"].update(run_settings(cfg, state["settings"]["suite"]))
    state["done"] = {k: v for k, v in state["done"].items() if k in BASE_STAGES}
    train0 = state["done"]["train-0"]
    train0["result"] = train0["result"].replace(str(base.resolve()), str(arm_dir.resolve()))
    (tmp / "run_state.json").write_text(json.dumps(state, indent=2))
    tmp.rename(arm_dir)


def eval_table(run_dir: Path, round_index: int) -> dict[str, float]:
    summary = json.loads(eval_summary(run_dir, round_index).read_text())
    return {row["task"]: row["success_rate"] for row in summary["per_task"]}


def phase_select(out: Path, candidates: str, name: str) -> None:
    """Round 0 of a policy trained on the candidate tasks: which start between 20 % and 70 %."""
    run_dir = out / name
    tasks = candidates.split(",")
    # The recipe's round-0 steps per task (3000 for 8 tasks): the same passes over each task's demos.
    steps = 3000 * len(tasks) // 8
    adademo_run(
        run_dir, f"--suite.tasks={candidates}", "--rounds=0", f"--train.steps={steps}", *seed_flags(0)
    )
    rates = eval_table(run_dir, 0)
    lines = [f"| {t} | {100 * sr:.0f} |" for t, sr in rates.items() if t != "average"]
    table = f"Candidates ({name}, {steps} steps):\n\n| task | round-0 SR % |\n| --- | --- |\n" + "\n".join(
        lines
    )
    write_summary_table(name, table)


def trained_schedule(run_dir: Path) -> str:
    """The learning-rate schedule a run trained with (runs from before it was recorded used the preset)."""
    return json.loads((run_dir / "run_state.json").read_text())["settings"].get("lr_schedule", "preset")


def retrain_round3(out: Path, arm: str, train_seed: int, lr_schedule: str) -> Path:
    """Seed 0's round-3 data of `arm` trained again (a run continued from that dataset, with the steps and sampler
    of the arm's own round-3 training) with another training seed and/or learning-rate schedule."""
    arm_dir = out / "seed0" / arm
    trained = json.loads((arm_dir / "run_state.json").read_text())["done"]["train-3"]["result"]
    steps = int(Path(trained).parent.name)  # .../checkpoints/<step>/pretrained_model
    name = f"{arm}_round3{'' if lr_schedule == 'preset' else '_' + lr_schedule}_trainseed{train_seed}"
    adademo_run(
        out / "noise" / name,
        f"--dataset.root={arm_dir / 'dataset'}",
        "--rounds=0",
        f"--train.steps={steps}",
        *ALL_ARMS[arm],
        f"--train.lr_schedule={lr_schedule}",
        "--seed=0",
        f"--train.seed={train_seed}",
    )
    return out / "noise" / name


def phase_noise(out: Path, arms: list[str], lr_schedule: str | None, train_seeds: list[int]) -> None:
    """The same round trained twice with different training seeds (1000, 2000), on unchanged data: how far the
    average moves. Without `lr_schedule` (each run's own schedule): round 0 of seed 0 (the base and a twin) and
    each finished seed-0 arm's round 3 (its own training, seed 1000, and a twin). With one: each arm's round-3 data
    trained with it (the arm's own training counts as seed 1000 if it used that schedule). `train_seeds` limits
    which trainings this call runs (two calls can share the machine)."""
    pairs, schedules = [], set()
    if lr_schedule is None:
        # The twin first: it needs no base, so a second driver can train it while the first builds the base.
        twin = out / "noise" / "base_trainseed2000"
        adademo_run(twin, "--rounds=0", "--seed=0", "--train.seed=2000")
        base = ensure_base(out, 0)
        if trained_schedule(twin) != trained_schedule(base):
            sys.exit(f"{twin} and {base} trained with different learning-rate schedules: use a fresh --out")
        schedules.add(trained_schedule(base))
        pairs.append(("round 0", eval_table(base, 0), eval_table(twin, 0)))
    for arm in arms:
        arm_dir = out / "seed0" / arm
        if not finished(arm_dir):
            continue
        schedule = lr_schedule or trained_schedule(arm_dir)
        schedules.add(schedule)
        runs = {1000: (arm_dir, 3)} if schedule == trained_schedule(arm_dir) else {}  # trained with seed 1000
        runs.update(
            (seed, (retrain_round3(out, arm, seed, schedule), 0)) for seed in train_seeds if seed not in runs
        )
        if set(runs) >= {1000, 2000}:
            first, second = (eval_table(*runs[1000]), eval_table(*runs[2000]))
            pairs.append((f"round 3 ({LABELS[arm].split(' (')[0]}'s data, seed 0)", first, second))
    rows = []
    for name, ra, rb in pairs:
        a, b = 100 * ra["average"], 100 * rb["average"]
        largest = max(abs(100 * (ra[t] - rb[t])) for t in ra if t != "average")
        rows.append(
            [name, f"{a:.1f}", f"{b:.1f}", f"{abs(a - b):.1f}", f"{(a + b) / 2:.1f}", f"{largest:.0f}"]
        )
    headers = [
        "trained",
        "avg SR % (train seed 1000)",
        "avg SR % (train seed 2000)",
        "difference",
        "mean of the two",
        "largest task difference",
    ]
    if rows:
        write_summary_table(
            "noise" if lr_schedule is None else f"noise_{lr_schedule}",
            f"Learning-rate schedule: {', '.join(sorted(schedules))}.\n\n"
            + table(headers, rows, aligned=False),
        )


def write_summary_table(name: str, text: str) -> None:
    """A `select` or `noise` table, committed beside the arms' summaries; `report` appends it."""
    from adademo_lerobot.core.files import atomic_write_text

    atomic_write_text(SUMMARIES / f"{name}.md", text + "\n")
    print(text)


def recipe_tasks(recipe: Path) -> list[str]:
    """The tasks a recipe's suite runs, as a run records them (group names such as `mt10` expanded)."""
    from adademo_lerobot.loop.cli import parse_config
    from adademo_lerobot.loop.run import RunConfig
    from adademo_lerobot.suites import make_suite

    return make_suite(parse_config(RunConfig, [f"--config_path={recipe}", "--run_dir=unused"]).suite).tasks


def export_run(out: Path, seed: int, arm: str) -> Path:
    """A finished arm's figures, small enough to commit: success and demos per task and round, the ledger (without
    machine paths and expert-failed states), the run's settings and the machine."""
    from adademo_lerobot.core.files import atomic_write_text
    from adademo_lerobot.dataset.ledger import read_ledger
    from adademo_lerobot.dataset.metadata import read_episode_metadata
    from adademo_lerobot.loop.failure_map import run_predictability
    from adademo_lerobot.loop.report import load_run

    run_dir = out / f"seed{seed}" / arm
    eps = read_episode_metadata(run_dir / "dataset")
    eps = eps[eps["adademo/round"] > 0]
    run = load_run(run_dir)
    if run.tasks != recipe_tasks(RECIPE):
        # A summary records the recipe it is read with; another recipe's name would be a false provenance.
        sys.exit(
            f"error: {run_dir} ran {', '.join(run.tasks)}, not the tasks of --recipe "
            f"{RECIPE.relative_to(ROOT)}: export it with the recipe it ran"
        )
    settings = json.loads((run_dir / "run_state.json").read_text())["settings"]
    summary = {
        "arm": arm,
        "seed": seed,
        "flags": [*ALL_ARMS[arm], *seed_flags(seed)],
        "recipe": str(RECIPE.relative_to(ROOT)),
        "machine": machine_line(),
        "settings": {k: v for k, v in settings.items() if not isinstance(v, str) or not v.startswith("/")},
        "tasks": run.tasks,
        "success": {t: run.success.loc[t].tolist() for t in run.tasks},
        "demos": {t: run.demos.loc[t].tolist() for t in run.tasks},
        "ledger": [
            {k: v for k, v in row.items() if k not in ("policy_path", "expert_failed_states")}
            for row in read_ledger(run_dir / "dataset")
        ],
        # The expansion rounds' episodes: where each started (a correction's takeover step) and its length.
        "episodes": [
            {"task": t, "round": int(r), "source": src, "start_step": int(step), "length": int(n)}
            for t, r, src, step, n in zip(
                eps.task,
                eps["adademo/round"],
                eps["adademo/source"],
                eps["adademo/start_step"],
                eps["length"],
                strict=True,
            )
        ],
        # How well the initial state predicts failure, per task, over every state each policy was evaluated on.
        "predictability": {
            p.task: {"auc": p.auc, "low": p.low, "high": p.high, "states": p.states, "failures": p.failures}
            for p in run_predictability(run_dir, run_dir / "dataset", run.tasks)[0]
        },
    }
    # `reread`: another run's data and weights evaluated again (for an arm branched from a reread base, its round 0's).
    if (run_dir / "reread_from.json").exists():
        summary["reread_from"] = json.loads((run_dir / "reread_from.json").read_text())
    path = SUMMARIES / f"seed{seed}-{arm}.json"
    atomic_write_text(path, json.dumps(summary, indent=1) + "\n")
    print(f"wrote {path.relative_to(ROOT)}", flush=True)
    return path


def phase_export(out: Path) -> None:
    """Summaries of every finished arm under `out` (for arms a driver from before `export_run` finished)."""
    for arm_dir in sorted(out.glob("seed*/*")):
        if arm_dir.name in ALL_ARMS and finished(arm_dir):
            export_run(out, int(arm_dir.parent.name.removeprefix("seed")), arm_dir.name)


def arm_status(run_dir: Path) -> dict:
    """Where a run folder of `arms` stands (a seed's base or an arm, finished or not): its stages done, the
    average success of each round evaluated so far, the demonstrations its expansion rounds added, and the hours
    its own stages took (an arm's from round 1 on: its round 0 is the base's, copied)."""
    done = json.loads((run_dir / "run_state.json").read_text())["done"]
    averages = []
    for summary in sorted((run_dir / "eval").glob("round-*/eval_summary.json")):
        rates = eval_table(run_dir, int(summary.parent.name.removeprefix("round-"))).values()
        averages.append(100 * sum(rates) / len(rates))
    added = sum(
        sum(stage["result"].get("demos_added", {}).values())
        for name, stage in done.items()
        if name.startswith("expand-")
    )
    own = [stage for name, stage in done.items() if run_dir.name == "base" or name not in BASE_STAGES]
    hours = sum(stage.get("seconds", 0.0) for stage in own) / 3600
    return {
        "stages": list(done),
        "averages": averages,
        "added": added,
        "hours": hours,
        "finished": finished(run_dir),
    }


def phase_status(out: Path) -> None:
    """A table of every run folder under `out`, for following a table that takes days (what `arms` would do next
    is each unfinished row's next stage). Hours are those of the stages done, on the machine that ran them: what
    an unfinished arm still needs is about a finished one's less its own."""
    print("| seed | run | stages done | average success by round, % | demos added | hours |")
    print("| --- | --- | --- | --- | --- | --- |")
    for state in sorted(out.glob("seed*/*/run_state.json")):
        run_dir = state.parent
        if run_dir.name.endswith(".copying"):  # a branch being copied from its base
            continue
        status = arm_status(run_dir)
        stages = "finished" if status["finished"] else (status["stages"] or ["none"])[-1] + " done"
        averages = " -> ".join(f"{a:.1f}" for a in status["averages"]) or "-"
        row = f"| {run_dir.parent.name} | {run_dir.name} | {stages} | {averages} | {status['added']} |"
        print(f"{row} {status['hours']:.1f} |")


def phase_arms(out: Path, seeds: list[int], arms: list[str]) -> None:
    """Every run of `pending_runs`, each by the first driver that takes it: the same command started again beside
    this one takes the next run this one does not hold, and waits only for a base whose arms it could run."""
    for seed in seeds:
        check_seed_pairs_here(seed)
    while pending := pending_runs(out, seeds, arms):
        for run_dir in pending:
            with claimed(run_dir) as ours:
                if ours and run_dir in pending_runs(out, seeds, arms):  # not finished since the list was made
                    run_one(out, run_dir)
                    break
        else:  # every run left is held by another driver
            bases = [run_dir for run_dir in pending if run_dir.name == "base"]
            if not bases:
                print(f"the {len(pending)} runs left are held by another driver", flush=True)
                return
            print(f"waiting for another driver's {bases[0]}: its arms come next", flush=True)
            with claimed(bases[0], wait=True):
                pass


def run_one(out: Path, run_dir: Path) -> None:
    """A seed's base (its round 0, then checked against the seed's summaries), or one arm from a copy of it."""
    seed = int(run_dir.parent.name.removeprefix("seed"))
    base = out / f"seed{seed}" / "base"
    if run_dir == base:
        build_base(base, seed)
    check_seed_pairs_here(seed, base)
    if run_dir != base:
        flags = [*ALL_ARMS[run_dir.name], *seed_flags(seed)]
        branch_from_base(base, run_dir, flags)
        adademo_run(run_dir, *flags)
        export_run(out, seed, run_dir.name)


# Runs whose data does not depend on the policy (a round-0 base, Uniform): they can be read again with another
# readout without collecting again; every other arm's rounds evaluate the policy to choose their states.
POLICY_FREE_ARMS = ("base", "uniform")


def recipe_policy(recipe: Path) -> dict:
    import yaml

    return yaml.safe_load(recipe.read_text())["train"]["policy"]


def copy_with_readout(src: Path, dst: Path, policy: dict) -> None:
    """`src` copied to `dst` with every kept checkpoint acting as `policy` does (its READOUT_FIELDS), and its
    evaluations dropped, so that rerunning it evaluates again. Refused if `policy` differs from a checkpoint in any
    other field that decides training."""
    import lerobot.policies  # noqa: F401  (registers the policy types by name)
    from lerobot.configs.policies import PreTrainedConfig

    # Where a policy runs or is stored, not what it is.
    from adademo_lerobot.loop.start import NOT_ARCHITECTURE

    defaults = PreTrainedConfig.get_choice_class(policy["type"])()
    readout = {f: policy.get(f, getattr(defaults, f)) for f in READOUT_FIELDS}
    kept = "train/round-*/checkpoints/*/pretrained_model/config.json"  # `last` links to one of them
    for config_path in sorted(p for p in src.glob(kept) if not p.parent.parent.is_symlink()):
        config = json.loads(config_path.read_text())
        differ = [
            k
            for k, v in policy.items()
            if k not in (*READOUT_FIELDS, *NOT_ARCHITECTURE) and k in config and config[k] != v
        ]
        if differ:
            sys.exit(f"{config_path} differs from --recipe in {differ}: not a readout")
    tmp = dst.with_name(dst.name + ".copying")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp, symlinks=True, ignore=shutil.ignore_patterns("eval", "report"))
    for config_path in sorted(p for p in tmp.glob(kept) if not p.parent.parent.is_symlink()):
        config_path.write_text(json.dumps(json.loads(config_path.read_text()) | readout, indent=4))
        train_config = config_path.with_name("train_config.json")
        trained = json.loads(train_config.read_text().replace(str(src.resolve()), str(dst.resolve())))
        trained["policy"] |= readout
        train_config.write_text(json.dumps(trained, indent=4))
    reread = {"from": str(src.resolve()), "readout": readout}  # the summary says where its data came from
    (tmp / "reread_from.json").write_text(json.dumps(reread, indent=2))
    state = json.loads((tmp / "run_state.json").read_text().replace(str(src.resolve()), str(dst.resolve())))
    state["done"] = {k: v for k, v in state["done"].items() if not k.startswith("eval-")}
    state.pop("interrupted", None)
    (tmp / "run_state.json").write_text(json.dumps(state, indent=2))
    tmp.rename(dst)


def phase_reread(src_out: Path, out: Path, seeds: list[int], arms: list[str]) -> None:
    """Each seed's base and `arms` (policy-free ones) of `src_out` read again under --recipe, whose policy differs
    from theirs only in READOUT_FIELDS: the same data and weights, evaluated again, nothing collected or trained."""
    if set(arms) - set(POLICY_FREE_ARMS):
        sys.exit(
            f"reread: {sorted(set(arms) - set(POLICY_FREE_ARMS))} choose their states with the policy: run them"
        )
    policy = recipe_policy(RECIPE)
    for seed in seeds:
        for arm in ["base", *arms]:
            src, dst = src_out / f"seed{seed}" / arm, out / f"seed{seed}" / arm
            if not dst.exists():
                if not (src / "run_state.json").exists():
                    sys.exit(f"reread: no run at {src}")
                dst.parent.mkdir(parents=True, exist_ok=True)
                copy_with_readout(src, dst, policy)
            flags = seed_flags(seed)
            adademo_run(dst, *flags, *(["--rounds=0", *BASE_FLAGS] if arm == "base" else ALL_ARMS[arm]))
            if arm != "base":
                export_run(out, seed, arm)


def phase_report(seeds: list[int], arms: list[str]) -> None:
    """benchmarks/results/<summaries>.md (and .png) from the committed summaries of `--summaries`."""
    from efficiency_report import write_report

    summaries = [json.loads(p.read_text()) for p in SUMMARIES.glob("seed*-*.json")]
    if not summaries:
        sys.exit(f"error: no summaries in {SUMMARIES} yet (seed<S>-<arm>.json): run `arms` first")
    machines = sorted({s["machine"].split("; machine: ")[-1] for s in summaries})
    tasks = summaries[0]["tasks"]
    # The recipe each run was exported with (summaries from before it was recorded: this command's --recipe).
    recipes = sorted({s.get("recipe", str(RECIPE.relative_to(ROOT))) for s in summaries})
    header = [
        f"Command: `python benchmarks/data_efficiency.py arms --seeds S.. --arms A.. --summaries {SUMMARIES.name}` "
        f"(two drivers, `--torch_threads 1`), then `report --summaries {SUMMARIES.name}`; report "
        f"{machine_line().split(';')[0]}; runs on {' / '.join(machines)} (each run's date in its summary under "
        f"`results/{SUMMARIES.name}/`). Trained policies differ across CPU vendors, so each seed's arms run on "
        "one kind of CPU (their shared round 0 says so: an arm whose round 0 differs from Uniform's is left out); "
        "seeds may come from different kinds, each paired within itself.",
        f"Recipe {', '.join(f'`{r}`' for r in recipes)} (tasks {', '.join(tasks)}): per seed every arm branches from one shared "
        "round 0 (dataset, policy, evaluation), trains each round from scratch with the same training seed, and is "
        "evaluated on the same fixed initial states; arms differ only in the flags of the script's `ALL_ARMS`.",
    ]
    labels = {arm: LABELS[arm] for arm in ALL_ARMS if arm in {"uniform", *arms}}
    out = RESULTS / f"{SUMMARIES.name}.md"
    write_report(SUMMARIES, labels, TITLES.get(SUMMARIES.name, "Data efficiency"), header, TAKEOVER_ARMS, out)
    extra = [*sorted(SUMMARIES.glob("select*.md")), *sorted(SUMMARIES.glob("noise*.md"))]
    if extra:  # the tables `select` and `noise` wrote, before the hand-written reading
        text = out.read_text()
        body, sep, reading = text.partition("\n## Reading")
        body += "".join(f"\n## {path.stem}\n\n{path.read_text()}" for path in extra)
        out.write_text(body + sep + reading)
    print(out.read_text())


TITLES = {
    "data_efficiency": "Data efficiency on MetaWorld: Uniform, AdaDemo, AdaDemo + tempered sampler, budgeted",
    "corrections": "Corrections from the point of failure on MetaWorld: takeover arms against Uniform and budgeted",
    "mt10": "Data efficiency on MetaWorld MT10: Uniform, AdaDemo, budgeted, budgeted + takeover corrections",
    "mt10_cost": "MetaWorld MT10, paying for rollouts: Uniform, task_only, budgeted and the rollout-cost arms",
    # MT10 on the Intel Xeon, whose round 0 differs from the EPYCs' (benchmarks/results/kernel_reproducibility.md):
    # costed_split with failure prediction (costed_split_knn) against a Uniform run of the same machine, per seed.
    "mt10_cost_xeon": "MetaWorld MT10 on an Intel Xeon, paying for rollouts: Uniform and the k-NN arms",
    # The second table: the same arms on the hard 8 (`recipes/budgeted.yaml`), 3 seeds, per-seed test states.
    "hard8_cost": "The hard 8 of MetaWorld, paying for rollouts: Uniform, task_only, budgeted and the rollout-cost arms",
    # The paper's Adroit table (`recipes/adroit_table.yaml`): the planner for hammer and pen, scripted door/relocate.
    "adroit": "Adroit (door, hammer, pen, relocate): Uniform, AdaDemo, budgeted, costed_split",
    # The same with hammer planned with common noise (`recipes/adroit_table_common_noise.yaml`).
    "adroit_common_noise": "Adroit, hammer planned with common noise: Uniform, AdaDemo, budgeted, costed_split",
    # The same, ACT acting by temporal ensembling (`recipes/adroit_table_ensembled.yaml`).
    "adroit_ensembled": "Adroit, ACT acting by temporal ensembling: Uniform, AdaDemo, budgeted, costed_split",
}
TAKEOVER_ARMS = {
    "costed_split_takeover",
    "budgeted_takeover",
    "adademo_takeover",
    "budgeted_takeover_backoff",
    "budgeted_takeover_retry3",
}


def main() -> None:
    global SUMMARIES, RECIPE
    parser = argparse.ArgumentParser()
    parser.add_argument("phase", choices=["select", "noise", "arms", "reread", "export", "status", "report"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--arms", nargs="+", choices=list(ALL_ARMS), default=list(ALL_ARMS))
    parser.add_argument("--out", type=Path, default=Path.home() / "adademo-bench")
    parser.add_argument("--torch_threads", type=int, default=None)
    parser.add_argument(
        "--from_out",
        type=Path,
        default=None,
        help="reread: the --out of the runs to read again under --recipe",
    )
    parser.add_argument("--candidates", default=CANDIDATES, help="select: comma-separated MetaWorld tasks")
    parser.add_argument("--name", default="select", help="select: the run's name under --out")
    parser.add_argument(
        "--lr_schedule", default=None, help="noise: retrain with it (default: each run's own)"
    )
    parser.add_argument("--train_seeds", type=int, nargs="+", default=[1000, 2000], help="noise: which ones")
    parser.add_argument(
        "--recipe",
        type=Path,
        default=RECIPE,
        help="the recipe every arm runs (its tasks, budgets and training); default recipes/budgeted.yaml",
    )
    parser.add_argument(
        "--summaries",
        default=SUMMARIES.name,
        help="folder under benchmarks/results for the summaries (paired by seed; a seed's arms on one kind of CPU)",
    )
    parser.add_argument(
        "--test_states",
        choices=["shared", "per_seed"],
        default="shared",
        help="per_seed: each seed's own fixed evaluation states (--eval.seed=100+seed); shared: eval seed 100's",
    )
    parser.add_argument(
        "--base_flags",
        default="",
        help="arms: adademo-run flags for building each seed's round-0 base only, e.g. '--executor=ray "
        "--ray.num_workers=2 --torch_threads=2' (Ray's collection equals the local one; the torch threads change "
        "the base's trained weights, so say which in the results)",
    )
    parser.add_argument(
        "--cpu_isa",
        choices=["avx2", "avx2_own_mkl", "native"],
        default="avx2",
        help="avx2 (default): the runs' kernels pinned to AVX2 and MKL's reproducible Intel AVX2 branch, on AMD CPUs "
        "too (a preloaded shim, built with cc): Intel and AMD machines train the same weights; avx2_own_mkl: the pin "
        "with MKL's own AMD kernels (AMD runs before 2026-12-08); native: the machine's own",
    )
    args = parser.parse_args()
    # For the runs this driver starts.
    if args.phase in ("select", "noise", "arms", "reread"):
        os.environ.update(
            {"avx2": avx2_kernels, "avx2_own_mkl": lambda: AVX2_KERNELS, "native": dict}[args.cpu_isa]()
        )
    SUMMARIES, RECIPE = RESULTS / args.summaries, args.recipe.resolve()
    TEST_STATES[0] = args.test_states
    SUMMARIES.mkdir(parents=True, exist_ok=True)
    BASE_FLAGS.extend(args.base_flags.split())
    if args.torch_threads is not None:
        TORCH_THREADS.append(f"--torch_threads={args.torch_threads}")
        os.environ["OMP_NUM_THREADS"] = str(args.torch_threads)
    if args.phase == "select":
        phase_select(args.out, args.candidates, args.name)
    elif args.phase == "noise":
        phase_noise(args.out, args.arms, args.lr_schedule, args.train_seeds)
    elif args.phase == "arms":
        phase_arms(args.out, args.seeds, args.arms)
    elif args.phase == "reread":
        if args.from_out is None:
            parser.error("reread needs --from_out (the runs to read again)")
        phase_reread(args.from_out, args.out, args.seeds, args.arms)
    elif args.phase == "export":
        phase_export(args.out)
    elif args.phase == "status":
        phase_status(args.out)
    else:
        phase_report(args.seeds, args.arms)  # every seed of the summaries folder


if __name__ == "__main__":
    main()
