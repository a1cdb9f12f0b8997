"""`adademo-report`: the paper's tables and figure for one run or several (`--compare`).

- per-task success and demos per round (Tables I/II and the appendix tables),
- average success vs average demos per task, one curve per run (Fig. 1),
- demo allocation per task per round, and the evaluation cost from the ledger;
- whether each task's failures concentrate in a region of initial states, and whether its demonstrations can be
  imitated at all (a score from the data alone);
- what each round cost per task (demonstrations, corrections, expert frames, evaluation episodes and steps) and
  success against each of these, added over the rounds (a person on a robot pays in expert time and episodes,
  not in demonstrations: `costs.py`), and, against a Uniform run (`--compare_to`), the break-even rollout
  cost.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from adademo_lerobot.collectors.base import expert_summary
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import check_writable_location
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.interventions import intervention_flags
from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import has_dataset, read_episode_metadata
from adademo_lerobot.loop.configs import ReportConfig
from adademo_lerobot.loop.report_costs import (
    break_even_summary,
    cost_lines,
    cost_rows,
    cost_table,
    pct,
    person_lines,
)
from adademo_lerobot.loop.report_plots import (
    plot_allocation,
    plot_eval_cost,
    plot_per_task_success,
    plot_success_vs_cost,
    plot_success_vs_demos,
)
from adademo_lerobot.loop.run_results import RunResults, describe_start
from adademo_lerobot.loop.run_state import read_run_state


def has_interventions(root: Path | None) -> bool:
    """Whether a run's dataset has LeRobot's DAgger `intervention` flags (its person's work is reported)."""
    return root is not None and has_dataset(root) and intervention_flags(root) is not None


def load_run(run_dir: Path) -> RunResults:
    run_dir = Path(run_dir)
    state = read_run_state(run_dir)
    if state is None:
        raise AdaDemoError(f"{run_dir} is not an adademo-run folder (no run_state.json)")
    settings = state["settings"]
    tasks = settings["suite"]["tasks"].split(",")
    # A run started from a user's dataset: its round r is the dataset's round base + r.
    begun = state["done"].get("start", {}).get("result", {})
    dataset_root = Path(begun.get("dataset_root", run_dir / "dataset"))
    base = begun.get("base_round", 0)
    success = {}
    for summary in sorted((run_dir / "eval").glob("round-*/eval_summary.json")):
        data = json.loads(summary.read_text())
        success[data["round"]] = {row["task"]: row["success_rate"] for row in data["per_task"]}
    if not success:
        raise AdaDemoError(f"{run_dir} has no evaluation results yet (eval/round-*/eval_summary.json)")
    eps = read_episode_metadata(dataset_root)
    rounds = sorted(success)
    demos = pd.DataFrame(
        {
            r: [int(((eps.task == t) & (eps["adademo/round"] <= base + r)).sum()) for t in tasks]
            for r in rounds
        },
        index=tasks,
    )
    rows = [r for r in read_ledger(dataset_root) if r["round"] > base]
    kept = eps.groupby(["task", "adademo/round"])["length"].sum()
    spent = cost_rows(rows, settings, kept).assign(round=lambda d: d["round"] - base)
    ledger = pd.DataFrame(rows)
    if len(ledger):
        ledger = ledger.assign(round=lambda d: d["round"] - base)
    corrections = " + takeover corrections" if settings.get("demo_start") == "takeover" else ""
    strategy = settings["strategy"]  # its config (a name in runs of release 0.2)
    name = strategy["type"] if isinstance(strategy, dict) else strategy
    label = f"{name}{corrections} + {settings['sampler']} sampler"
    return RunResults(
        run_dir.name,
        label,
        tasks,
        pd.DataFrame(success).loc[tasks + ["average"], rounds],
        demos,
        ledger,
        describe_start(begun),
        run_dir,
        dataset_root,
        base,
        spent,
    )


def markdown_tables(run: RunResults) -> str:
    rounds = list(run.success.columns)
    rows = [
        [t, *(f"{pct(run.success.loc[t, r])} ({run.demos.loc[t, r]})" for r in rounds)] for t in run.tasks
    ]
    rows.append(
        [
            "**average**",
            *(f"**{pct(run.success.loc['average', r])}** ({run.demos[r].mean():.1f})" for r in rounds),
        ]
    )
    header = ["task", *(f"round {r}: SR % (demos)" for r in rounds)]
    lines = [f"### {run.name} — {run.label}", ""]
    if run.started_from:
        lines += [run.started_from, ""]
    lines += [table(header, rows, aligned=False)]
    if len(run.ledger):
        ledger = run.ledger.reindex(
            columns=[*run.ledger.columns, *({"corrections", "demo_frames"} - set(run.ledger.columns))],
            fill_value=0,
        )
        rows = [
            [
                r,
                g.strategy.iloc[0],
                g.demos_added.sum(),
                int(g.corrections.sum()),
                g.eval_episodes.sum(),
                g.eval_env_steps.sum(),
                g.collection_env_steps.sum(),
                int(g.demo_frames.sum()),
                g.expert_failures.sum(),
                int(g.cap_hit.sum()),
            ]
            for r, g in ledger.groupby("round")
        ]
        lines += [
            "",
            "Expansion rounds (from the ledger):",
            "",
            table(
                [
                    "round",
                    "strategy",
                    "demos added",
                    "corrections",
                    "eval episodes",
                    "eval env steps",
                    "expert frames (collection env steps)",
                    "demo frames",
                    "expert failures",
                    "tasks at CAP",
                ],
                rows,
                aligned=False,
            ),
        ]
        lines += expert_lines(ledger)
        lines += cost_lines(run, ledger)
        lines += allocation_lines(run.ledger)
    return "\n".join(lines)


def expert_lines(ledger: pd.DataFrame) -> list[str]:
    """Which expert demonstrated each round, with the settings that differ from its defaults (rounds written
    before the ledger recorded it are left out)."""
    if "collector" not in ledger.columns:
        return []
    experts = {
        r: expert_summary(g.collector.iloc[0])
        for r, g in ledger.groupby("round")
        if isinstance(g.collector.iloc[0], dict) and g.collector.iloc[0]
    }
    if not experts:
        return []
    spans: list[tuple[list[int], str]] = []  # consecutive rounds with one expert, as one entry
    for r, name in experts.items():
        if spans and spans[-1][1] == name and spans[-1][0][-1] == r - 1:
            spans[-1][0].append(r)
        else:
            spans.append(([r], name))
    named = [
        f"{f'rounds {rs[0]}-{rs[-1]}' if len(rs) > 1 else f'round {rs[0]}'}: {name}" for rs, name in spans
    ]
    return ["", f"Expert (`collector` in the ledger): {'; '.join(named)}."]


def load_uniform(path: Path, run: RunResults) -> RunResults:
    """The Uniform run to read c* against: a run on the same tasks that ran no policy rollouts."""
    try:
        state = read_run_state(path)
    except AdaDemoError as err:
        raise AdaDemoError(f"--compare_to: {err}") from None
    if state is None:
        raise AdaDemoError(f"--compare_to: {path} is not an adademo-run folder (no run_state.json)")
    tasks = state["settings"]["suite"]["tasks"].split(",")
    if set(tasks) != set(run.tasks):  # checked before loading: its results are of other tasks
        raise AdaDemoError(
            f"--compare_to: {path} ran other tasks ({','.join(tasks)}) than {run.run_dir} "
            f"({','.join(run.tasks)}): the break-even cost compares runs on the same tasks"
        )
    try:
        uniform = load_run(path)
    except AdaDemoError as err:
        raise AdaDemoError(f"--compare_to: {err}") from None
    rollouts = int(uniform.costs["rollouts"].sum())
    if rollouts:
        raise AdaDemoError(
            f"--compare_to: {path} ran {rollouts} policy rollouts in its expansion rounds; compare with a "
            "Uniform run (--strategy.type=uniform), which runs none"
        )
    return uniform


def failure_lines(run: RunResults, out_dir: Path) -> list[str]:
    """Will AdaDemo help here? Per task, how well the initial state predicts failure, and the failure map."""
    from adademo_lerobot.loop.failure_map import plot_failure_map, run_predictability

    results, by_round = run_predictability(run.run_dir, run.dataset_root, run.tasks, run.base_round)
    if not by_round:
        return []
    plot_failure_map(by_round, run.tasks, out_dir / f"failure_map_{run.name}.png")
    rows = [
        [
            r.task,
            r.states,
            r.failures,
            "-" if r.auc is None else f"{r.auc:.2f} [{r.low:.2f}, {r.high:.2f}]",
            r.reading,
        ]
        for r in results
    ]
    return [
        "Will AdaDemo help on these tasks? How well a task's initial state predicts the policy's failure (AUC of a "
        "cross-validated 5-nearest-neighbour vote over the initial states each policy was evaluated on; 0.5 is "
        "chance; 95 % interval):",
        "",
        table(["task", "states", "failures", "AUC", "reading"], rows, aligned=False),
        "",
        f"![failure map](failure_map_{run.name}.png)",
        "",
    ]


def imitability_lines(root: Path, tasks: list[str] | None = None) -> list[str]:
    """Can a policy imitate each task's demonstrations? A score from the data alone (`imitability.py`)."""
    from adademo_lerobot.dataset.imitability import AGREE, DEMONSTRATIONS, DISAGREE, demonstration_agreement

    try:
        results = demonstration_agreement(root, tasks)
    except AdaDemoError as err:  # the rest of the report stands without it
        return [f"Can a policy imitate these demonstrations? Not scored: {err}.", ""]
    if not results:
        return []
    rows = [
        [a.task, a.demonstrations, "-" if a.score is None else f"{a.score:.2f}", a.reading] for a in results
    ]
    return [
        "Can a policy imitate these demonstrations? Per task, from its first "
        f"{DEMONSTRATIONS} demonstrations and no policy: the share of their action variance that the mean action "
        "at the 5 nearest states of the task's other demonstrations explains (1: similar states got similar "
        f"actions; about -0.2: unrelated actions; below {DISAGREE}: they disagree; from {AGREE}: consistent):",
        "",
        table(["task", "demonstrations", "score", "reading"], rows, aligned=False),
        "",
    ]


def allocation_lines(ledger: pd.DataFrame) -> list[str]:
    """Per round and task, what was planned and what was done, and (budgeted) the success estimate before and
    after the round's evaluations."""
    rows = []
    for _, r in ledger.iterrows():
        extra = r.get("extra") if isinstance(r.get("extra"), dict) else {}
        estimate = ""
        if extra.get("prior") and extra.get("posterior"):
            (a0, b0), (a1, b1) = extra["prior"], extra["posterior"]
            estimate = f"{100 * a0 / (a0 + b0):.0f} -> {100 * a1 / (a1 + b1):.0f}"
        planned = "" if pd.isna(r.get("planned_demos")) else int(r["planned_demos"])
        rows.append([r["round"], r["task"], planned, r["demos_added"], r["eval_episodes"], estimate])
    if not any(row[2] != "" or row[5] for row in rows):
        return []
    return [
        "",
        "Allocation per round (planned: the budget's first split or ablation A's N_k; success estimate: the "
        "posterior mean before -> after the round's evaluations, %):",
        "",
        table(
            ["round", "task", "planned demos", "demos", "eval episodes", "success estimate"],
            rows,
            aligned=False,
        ),
    ]


def write_report(run_dirs: list[Path], out_dir: Path, uniform: RunResults | None = None) -> Path:
    """The report of `run_dirs` (the first with its break-even rollout cost against `uniform`, if given)."""
    runs = [load_run(Path(d)) for d in run_dirs]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plot_success_vs_demos(runs, out_dir / "success_vs_demos.png")
    plot_eval_cost(runs, out_dir / "eval_cost.png")
    plot_success_vs_cost(runs, out_dir / "success_vs_cost.png")
    sections = [
        "# AdaDemo report",
        "",
        "![success vs demos](success_vs_demos.png)",
        "",
        "![success vs demonstrations, expert frames and episodes](success_vs_cost.png)",
        "",
    ]
    if len(runs) > 1:
        rows = [
            [
                run.name,
                run.label,
                pct(run.success.loc["average", run.success.columns[-1]]),
                f"{run.demos[run.success.columns[-1]].mean():.1f}",
            ]
            for run in runs
        ]
        sections += [
            table(["run", "strategy", "final avg SR %", "avg demos per task"], rows, aligned=False),
            "",
        ]
    for i, run in enumerate(runs):
        plot_allocation(run, out_dir / f"allocation_{run.name}.png")
        plot_per_task_success(run, out_dir / f"success_{run.name}.png")
        sections += [
            markdown_tables(run),
            "",
            *([*break_even_summary(run, uniform), ""] if i == 0 else []),
            f"![allocation](allocation_{run.name}.png) ![per-task success](success_{run.name}.png)",
            "",
            *failure_lines(run, out_dir),
            *imitability_lines(run.dataset_root, run.tasks),
            *(
                [*person_lines(run.dataset_root), ""]
                if i == 0 and has_interventions(run.dataset_root)
                else []
            ),
        ]
    sections += ["## Evaluation cost", "", "![evaluation cost](eval_cost.png)", ""]
    path = out_dir / "report.md"
    path.write_text("\n".join(sections))
    return path


def dataset_report(root: Path, output_dir: str | None) -> Path | None:
    """`--dataset_root`: the person's work in a dataset (no run folder) and whether each task's demonstrations
    can be imitated, printed, and written to `output_dir`."""
    if not has_dataset(root):
        raise AdaDemoError(f"--dataset_root: no LeRobot dataset at {root} (missing meta/info.json)")
    lines = [*person_lines(root), "", *imitability_lines(root)]
    print("\n".join(lines))
    if output_dir is None:
        return None
    path = Path(output_dir) / "report.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(["# AdaDemo report", "", *lines, ""]))
    print(f"report: {path}")
    return path


def run_report(cfg: ReportConfig) -> Path | None:
    compare_to = getattr(cfg, "compare_to", None)  # ReportConfig's field (configs.py)
    if cfg.run_dir is None and cfg.dataset_root is not None:
        if cfg.compare or compare_to:
            raise AdaDemoError(
                "--compare and --compare_to compare run folders with --run_dir's; a --dataset_root report has "
                "no run to compare: drop them, or give --run_dir"
            )
        if cfg.output_dir is not None:
            check_writable_location(Path(cfg.output_dir), "--output_dir")
        return dataset_report(Path(cfg.dataset_root), cfg.output_dir)
    if cfg.run_dir is None:
        raise AdaDemoError("--run_dir is required (or --dataset_root, for a dataset recorded on a robot)")
    out = Path(cfg.output_dir) if cfg.output_dir else Path(cfg.run_dir) / "report"
    run = load_run(Path(cfg.run_dir))
    # A bad --compare_to or output folder is refused before anything is written.
    check_writable_location(out, "--output_dir")
    uniform = load_uniform(Path(compare_to), run) if compare_to else None
    path = write_report([Path(cfg.run_dir), *map(Path, cfg.compare)], out, uniform)
    print("\n".join([*cost_table(run), "", *break_even_summary(run, uniform)]))
    print(f"report: {path}")
    return path
