"""`adademo-expand`: one round of dataset expansion (Algorithm 1, lines 3-17) with any strategy.

Everything the round decides is journaled before it acts (see `ledger.py`), every dataset append is a
transaction (see `dataset/store.py`), so `kill -9` at any moment followed by the same command finishes the
same round: no initial state gets two demonstrations in a round and the ledger matches the dataset.

The round number is decided once (`next_round`, or given by `adademo-run`) and passed down; a journal left by a
kill between the ledger write and the journal's end is finished, never mistaken for the round in progress.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from pathlib import Path

from tqdm import tqdm

from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.layout import COL_ROUND
from adademo_lerobot.dataset.metadata import has_dataset, load_suite_config, read_episode_metadata
from adademo_lerobot.dataset.store import DemoDataset, recover_interrupted_write
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.executors import check_executor_args, make_executor
from adademo_lerobot.files import exclusive_use
from adademo_lerobot.ledger import RoundJournal, append_ledger, ledger_rounds
from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.strategies import make_strategy, planned_demos
from adademo_lerobot.strategies.base import RoundContext
from adademo_lerobot.strategies.budgeted import failure_mean, pick_target_successes, prior_from_earlier_rounds
from adademo_lerobot.strategies.task_only import estimate_success
from adademo_lerobot.suites import make_suite
from adademo_lerobot.tables import table
from adademo_lerobot.takeover import check_demo_start

DEFAULT_TARGET_SUCCESSES = 10


def validate(cfg) -> None:
    strategy = make_strategy(cfg.strategy)
    check_demo_start(cfg.demo_start, cfg.takeover)
    if cfg.demo_start == "takeover" and not strategy.collects_at_failed_states:
        raise AdaDemoError(
            f"--demo_start=takeover corrects failed policy rollouts; --strategy={cfg.strategy} collects from fresh "
            "initial states without evaluating: use --strategy=adademo or budgeted, or --demo_start=initial"
        )
    for flag, value in (
        ("target_successes", cfg.target_successes),
        ("max_demos_per_task", cfg.max_demos_per_task),
        ("demos_per_task", cfg.demos_per_task),
        ("plan_episodes_per_task", cfg.plan_episodes_per_task),
    ):
        if value is not None and value < 1:
            raise AdaDemoError(f"--{flag} must be >= 1, got {value}")
    if cfg.budget is not None and cfg.budget < 1:
        raise AdaDemoError(f"--budget must be >= 1 (demonstrations in the round), got {cfg.budget}")
    if cfg.budget is not None and cfg.target_successes is not None:
        raise AdaDemoError(
            f"--budget={cfg.budget} and --target_successes={cfg.target_successes} both set the round's size: "
            "pass one (with --budget, E is picked to fit it)"
        )
    if cfg.strategy == "budgeted" and cfg.budget is None:
        raise AdaDemoError("--strategy=budgeted needs --budget=B (demonstrations in the round)")
    if not 0 < cfg.posterior_decay <= 1:
        raise AdaDemoError(f"--posterior_decay must be in (0, 1], got {cfg.posterior_decay}")
    if cfg.max_eval_episodes_per_task is not None and cfg.max_eval_episodes_per_task < 1:
        raise AdaDemoError(f"--max_eval_episodes_per_task must be >= 1, got {cfg.max_eval_episodes_per_task}")
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (an adademo dataset made by adademo-collect)")
    if not has_dataset(cfg.dataset.root):
        raise AdaDemoError(f"no LeRobot dataset at {cfg.dataset.root}; create one with adademo-collect")


def target_successes_for(cfg, root: Path, suite, round_index: int) -> int:
    """E: the flag, the default, or (with --budget, for adademo and task_only) the largest E whose predicted
    total fits the budget, from each task's success estimate over the earlier rounds' evaluations."""
    if cfg.target_successes is not None:
        return cfg.target_successes
    if cfg.budget is None or cfg.strategy not in ("adademo", "task_only"):
        return DEFAULT_TARGET_SUCCESSES
    rates = {
        t: 1 - failure_mean(prior_from_earlier_rounds(root, round_index, t, cfg.posterior_decay))
        for t in suite.tasks
    }
    target, plan = pick_target_successes(cfg.budget, rates, cfg.max_demos_per_task)
    print(
        f"budget {cfg.budget}: picked E={target} (predicted demos "
        + ", ".join(f"{t} {n}" for t, n in plan.items())
        + f"; total {sum(plan.values())})"
    )
    return target


def demo_start_settings(cfg) -> dict:
    """The round's demonstration start, as journaled (absent for the paper's: rounds journaled before it existed
    resume unchanged)."""
    if cfg.demo_start == "initial":
        return {}
    return {"demo_start": cfg.demo_start, "takeover": cfg.takeover.to_dict()}


def next_round(root: Path) -> int:
    """The round in progress (journaled and not in the ledger), else one past the last round of the ledger or
    the dataset. Reads only."""
    done = ledger_rounds(root)
    unfinished = [r for r in RoundJournal.in_progress(root) if r not in done]
    if unfinished:
        return unfinished[0]
    eps = read_episode_metadata(root)
    return max([0, *done, *(eps[COL_ROUND].tolist() if len(eps) else [])]) + 1


def finish_stale_journals(root: Path) -> None:
    """A kill between the ledger write and the journal's end leaves a journal of a complete round: archive it."""
    done = ledger_rounds(root)
    for r in RoundJournal.in_progress(root):
        if r in done:
            RoundJournal(root, r).finish()


def format_round_table(records: list[TaskRoundRecord]) -> str:
    def row(r: TaskRoundRecord):
        sr = f"{100 * r.success_rate:.0f}%" if r.success_rate is not None else "-"
        return (
            r.task,
            r.eval_episodes,
            sr,
            r.demos_added,
            r.expert_failures,
            "yes" if r.cap_hit else "",
            r.eval_env_steps,
            r.collection_env_steps,
        )

    rows = [row(r) for r in records]
    rows.append(
        (
            "total",
            sum(r.eval_episodes for r in records),
            "",
            sum(r.demos_added for r in records),
            sum(r.expert_failures for r in records),
            "",
            sum(r.eval_env_steps for r in records),
            sum(r.collection_env_steps for r in records),
        )
    )
    return table(["task", "eval", "SR", "demos", "expert fail", "cap", "eval steps", "collect steps"], rows)


def plan(cfg, suite, ctx: RoundContext) -> list[dict]:
    """Evaluate and predict each task's demos without collecting (price a round before paying for it)."""
    rows = []
    for task in tqdm(suite.tasks, desc="planning", unit="task", dynamic_ncols=True):
        record = ctx.new_record(task, "plan")
        sr = estimate_success(ctx, task, record)
        rows.append(
            {
                "task": task,
                "episodes": record.eval_episodes,
                "successes": record.successes,
                "success_rate": sr,
                "predicted_demos": planned_demos(cfg.target_successes, sr, cfg.max_demos_per_task),
            }
        )
    print(
        f"plan for round {ctx.round_index} (E={cfg.target_successes}, CAP={cfg.max_demos_per_task}); nothing collected"
    )
    body = [
        (
            r["task"],
            f"{r['successes']}/{r['episodes']}",
            f"{100 * r['success_rate']:.0f}%",
            r["predicted_demos"],
        )
        for r in rows
    ]
    body.append(("total", "", "", sum(r["predicted_demos"] for r in rows)))
    print(table(["task", "success", "SR", "predicted demos"], body))
    print(f"({ctx.eval_env_steps} evaluation env steps)")
    return rows


def run_expand(cfg, round_index: int | None = None, executor=None) -> list[TaskRoundRecord] | list[dict]:
    """One round. `round_index` is given by adademo-run (its one truth); alone, the command finds the next one.
    `executor`: adademo-run's, kept across rounds (else one is made from the flags for this round)."""
    validate(cfg)
    check_executor_args(cfg.executor, cfg.ray)
    root = Path(cfg.dataset.root)
    strategy = make_strategy(cfg.strategy)
    needs_policy = strategy.needs_policy or cfg.plan_only
    if needs_policy and cfg.policy.path is None:
        raise AdaDemoError(f"--strategy={cfg.strategy} evaluates a policy: pass --policy.path=CKPT")
    with exclusive_use(root, "adademo-expand") if not cfg.plan_only else nullcontext():
        if not cfg.plan_only:
            recover_interrupted_write(root)  # a write a kill left half-done is ours to roll back
        check_dataset_integrity(root)  # refuse a damaged dataset before anything is written
        suite = make_suite(load_suite_config(root))
        if not cfg.plan_only:
            cfg.collector.validate(suite)
            if cfg.demo_start == "takeover":
                cfg.collector.check_acts_mid_episode(suite)
        if needs_policy:
            from adademo_lerobot.policy import check_policy

            check_policy(cfg.policy.path, dataset_features(suite))
        own_executor = executor is None
        if own_executor:
            executor = make_executor(
                cfg.executor,
                cfg.ray,
                suite,
                cfg.collector,
                cfg.eval.batch_size,
                cfg.device,
                cfg.torch_threads,
            )
        try:
            executor.use_policy(str(cfg.policy.path) if needs_policy else None)
            return _expand(cfg, suite, executor, strategy, needs_policy, root, round_index)
        finally:
            if own_executor:
                executor.close()


def _expand(cfg, suite, executor, strategy, needs_policy, root, round_index):
    dataset = (
        DemoDataset(cfg.dataset.repo_id, root, suite.config)
        if cfg.plan_only
        else DemoDataset.open(cfg.dataset.repo_id, root)
    )
    if round_index is None:
        round_index = next_round(root)
    journal = RoundJournal(root, round_index)
    started = journal.of_type(
        "start"
    )  # a resumed round keeps the E it picked (the estimate would now differ)
    if (
        started
        and cfg.target_successes is None
        and started[0].get("target_successes") is not None
        and cfg.budget
    ):
        target = started[0]["target_successes"]
    else:
        target = target_successes_for(cfg, root, suite, round_index)
    max_eval = cfg.max_eval_episodes_per_task or 2 * (target + cfg.max_demos_per_task)
    settings = {
        "target_successes": target,
        "max_demos_per_task": cfg.max_demos_per_task,
        "demos_per_task": cfg.demos_per_task,
        "max_eval_episodes_per_task": max_eval,
        "plan_episodes_per_task": cfg.plan_episodes_per_task,
        "commit_every": cfg.commit_every,
        "policy_path": str(cfg.policy.path) if needs_policy else None,
        "budget": cfg.budget,
        "posterior_decay": cfg.posterior_decay,
        "commit_by_task": not hasattr(strategy, "expand_round"),
        "takeover": cfg.takeover if cfg.demo_start == "takeover" else None,
    }
    expert = cfg.collector.expert_name(suite)
    if cfg.plan_only:
        ctx = RoundContext(suite, dataset, executor, expert, round_index, cfg.seed, source="plan", **settings)
        return plan(cfg, suite, ctx)

    finish_stale_journals(root)
    if round_index in ledger_rounds(root):
        print(f"round {round_index} is already complete (meta/adademo/rounds.jsonl)")
        return []
    journal.start(
        {
            "strategy": cfg.strategy,
            "target_successes": target,
            "max_demos_per_task": cfg.max_demos_per_task,
            "demos_per_task": cfg.demos_per_task,
            "budget": cfg.budget,
            "posterior_decay": cfg.posterior_decay,
            "plan_episodes_per_task": cfg.plan_episodes_per_task,
            "max_eval_episodes_per_task": max_eval,
            "seed": cfg.seed,
            "policy_path": str(Path(cfg.policy.path).resolve()) if needs_policy else None,
            **demo_start_settings(cfg),
        }
    )
    bar = tqdm(
        total=len(suite.tasks), desc=f"round {round_index} ({cfg.strategy})", unit="task", dynamic_ncols=True
    )

    def progress(task: str, record: TaskRoundRecord) -> None:
        bar.set_postfix(
            task=task, evals=record.eval_episodes, ok=record.successes, demos=record.demos_added, refresh=True
        )

    ctx = RoundContext(
        suite,
        dataset,
        executor,
        expert,
        round_index,
        cfg.seed,
        source=cfg.strategy,
        journal=journal,
        on_progress=progress,
        **settings,
    )

    if hasattr(strategy, "expand_round"):  # decisions that span tasks: one loop over the whole round
        started_at = time.perf_counter()
        records = strategy.expand_round(ctx)
        ctx.flush()
        bar.update(len(suite.tasks))
        share_round_time(records, time.perf_counter() - started_at, journal)
    else:

        def expand_task(task: str) -> TaskRoundRecord:
            record = strategy.expand_task(ctx, task)
            bar.update(1)
            return record

        records = ctx.run_tasks(expand_task)
    bar.close()
    for record in records:
        ctx.evaluation_cost(record.task, record)
        record.wall_seconds = round(journal.seconds(record.task), 3)
    check_ledger_matches_dataset(root, round_index, records)
    append_ledger(root, records)
    _after_ledger_written()
    journal.finish()
    print(format_round_table(records))
    print(f"round {round_index}: {sum(r.demos_added for r in records)} new episodes in {root}")
    return records


def share_round_time(records: list[TaskRoundRecord], seconds: float, journal: RoundJournal) -> None:
    """A round-wide loop journals its time per task in proportion to each task's env steps."""
    steps = {
        r.task: r.collection_env_steps + sum(e["steps"] for e in journal.evaluations(r.task).values())
        for r in records
    }
    total = sum(steps.values()) or 1
    journal.append(*({"type": "time", "task": t, "seconds": seconds * n / total} for t, n in steps.items()))


def _after_ledger_written() -> None:
    """The point between the ledger write and the journal's end (a kill here must not lose the next round).
    Tests set ADADEMO_TEST_KILL_AFTER_LEDGER=1 to die exactly here."""
    import os

    if os.environ.get("ADADEMO_TEST_KILL_AFTER_LEDGER") == "1":
        os.kill(os.getpid(), 9)


def check_ledger_matches_dataset(root: Path, round_index: int, records: list[TaskRoundRecord]) -> None:
    eps = read_episode_metadata(root)
    counts = eps[eps[COL_ROUND] == round_index].groupby("task").size()
    for r in records:
        if int(counts.get(r.task, 0)) != r.demos_added:
            raise RuntimeError(
                f"internal error: round {round_index} {r.task}: ledger {r.demos_added} demos, "
                f"dataset {int(counts.get(r.task, 0))}"
            )
