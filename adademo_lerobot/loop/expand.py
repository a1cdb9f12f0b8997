"""`adademo-expand`: one round of dataset expansion (Algorithm 1, lines 3-17) with any strategy.

Everything the round decides is journaled before it acts (see `ledger.py`), every dataset append is a
transaction (see `dataset/store.py`), so `kill -9` at any moment followed by the same command finishes the
same round: no initial state gets two demonstrations in a round and the ledger matches the dataset.

The round number is decided once (`next_round`, or given by `adademo-run`) and passed down; a journal left by a
kill between the ledger write and the journal's end is finished, never mistaken for the round in progress.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path

from tqdm import tqdm

from adademo_lerobot.collectors.takeover import check_can_take_over
from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.progress import show
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.interventions import check_episode_stats
from adademo_lerobot.dataset.layout import COL_ROUND, COL_SOURCE, POLICY_SOURCE
from adademo_lerobot.dataset.ledger import RoundJournal, append_ledger, ledger_rounds
from adademo_lerobot.dataset.metadata import has_dataset, load_suite_config, read_episode_metadata
from adademo_lerobot.dataset.shards import remove_shard_folders
from adademo_lerobot.dataset.store import DemoDataset, recover_interrupted_write
from adademo_lerobot.executors import make_executor
from adademo_lerobot.loop.run_state import config_field_defaults
from adademo_lerobot.strategies import planned_demos
from adademo_lerobot.strategies.base import PlanningStrategy
from adademo_lerobot.strategies.round_context import RoundContext
from adademo_lerobot.strategies.task_only import estimate_success
from adademo_lerobot.suites import make_suite


def journaled_round_settings(cfg) -> dict:
    """The round's demonstration start and whether it keeps successes, as journaled (absent for the paper's:
    rounds journaled before they existed resume unchanged)."""
    settings = {"keep_successes": True} if cfg.keep_successes else {}
    if cfg.demo_start == "initial":
        return settings
    return settings | {"demo_start": cfg.demo_start, "takeover": cfg.takeover.to_dict()}


def plan_header(round_index: int, target: int, cap: int, caps: dict[str, int]) -> str:
    """The plan's first line: E, CAP, and the tasks whose CAP is lower this round (`limit_disagreeing`)."""
    lower = "".join(f", {task} {n}" for task, n in caps.items() if n != cap)
    return f"plan for round {round_index} (E={target}, CAP={cap}{lower}); nothing collected"


def unfinished_rounds(root: Path, done: set[int] | None = None) -> list[int]:
    """Rounds journaled and not in the ledger (a journal of a round in the ledger is of a finished round whose
    archiving a kill prevented: `finish_stale_journals`); `done`: the ledger's rounds if already read. Reads only."""
    done = ledger_rounds(root) if done is None else done
    return [r for r in RoundJournal.in_progress(root) if r not in done]


def next_round(root: Path) -> int:
    """The round in progress (`unfinished_rounds`), else one past the last round of the ledger or the dataset.
    Reads only."""
    done = ledger_rounds(root)
    unfinished = unfinished_rounds(root, done)
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


def plan(cfg, suite, ctx: RoundContext, strategy: PlanningStrategy) -> list[dict]:
    """Evaluate and predict each task's demos with the strategy's E and CAP, without collecting (price a round
    before paying for it)."""
    strategy.start(ctx, None)
    target, cap = strategy.target_successes, strategy.cap
    rows = []
    for task in tqdm(suite.tasks, desc="planning", unit="task", dynamic_ncols=True):
        record = ctx.new_record(task, "plan")
        sr = estimate_success(ctx, task, record, cfg.plan_episodes_per_task)
        rows.append(
            {
                "task": task,
                "episodes": record.eval_episodes,
                "successes": record.successes,
                "success_rate": sr,
                "predicted_demos": planned_demos(target, sr, strategy.task_cap(task)),
            }
        )
    print(plan_header(ctx.round_index, target, cap, {t: strategy.task_cap(t) for t in suite.tasks}))
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


def run_expand(
    cfg,
    round_in_run: int | None = None,
    round_index: int | None = None,
    executor=None,
    on_ledger_written: Callable[[int], None] | None = None,
) -> list[TaskRoundRecord] | list[dict]:
    """One round. Alone (`adademo-expand`), the round after the dataset's last, with the strategy's one value per
    setting; from adademo-run, the run's round `round_in_run` (its per-round values) as the dataset's round
    `round_index` (the run's one truth), on the run's `executor` (kept across rounds). `on_ledger_written(round)`
    is called between the ledger write and the journal's end (a kill there must not lose the next round: the
    tests kill the process from it)."""
    if round_in_run is None:
        cfg.validate()  # adademo-expand's own round
    else:
        cfg.validate_round()  # adademo-run's round i (its per-round values were checked by the run)
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (an adademo dataset made by adademo-collect)")
    if not has_dataset(cfg.dataset.root):
        raise AdaDemoError(f"no LeRobot dataset at {cfg.dataset.root}; create one with adademo-collect")
    root = Path(cfg.dataset.root)
    strategy = cfg.strategy.build(round_in_run or 1)
    needs_policy = cfg.strategy.needs_policy or cfg.plan_only
    if needs_policy and cfg.policy.path is None:
        raise AdaDemoError(f"--strategy.type={cfg.strategy.type} evaluates a policy: pass --policy.path=CKPT")
    with exclusive_use(root, "adademo-expand") if not cfg.plan_only else nullcontext():
        if not cfg.plan_only:
            recover_interrupted_write(root)  # a write a kill left half-done is ours to roll back
        check_dataset_integrity(root)  # refuse a damaged dataset before anything is written
        suite = make_suite(load_suite_config(root))
        if not cfg.plan_only:
            # Before the round's journal: an append would leave it unreadable by stock LeRobot.
            check_episode_stats(root)
            cfg.collector.validate(suite)
            if cfg.demo_start == "takeover":
                check_can_take_over(suite, cfg.collector)
        if needs_policy:
            from adademo_lerobot.evaluation.policy import check_policy

            check_policy(cfg.policy.path, dataset_features(suite))
        own_executor = executor is None
        if own_executor:
            executor = make_executor(cfg, suite, cfg.collector, cfg.eval.batch_size)
        try:
            executor.use_policy(str(cfg.policy.path) if needs_policy else None)
            return _expand(cfg, suite, executor, strategy, needs_policy, root, round_index, on_ledger_written)
        finally:
            if own_executor:
                executor.close()


def _expand(cfg, suite, executor, strategy, needs_policy, root, round_index, on_ledger_written=None):
    dataset = (
        DemoDataset(cfg.dataset.repo_id, root, suite.config)
        if cfg.plan_only
        else DemoDataset.open(cfg.dataset.repo_id, root)
    )
    if round_index is None:
        round_index = next_round(root)
    journal = None if cfg.plan_only else RoundJournal(root, round_index)
    # No rate or time left: tasks differ too much in cost (and a resumed task ends at once) for either to mean much.
    bar = tqdm(
        total=len(suite.tasks), desc=f"round {round_index} ({strategy.name})", unit="task", dynamic_ncols=True,
        disable=cfg.plan_only, bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]",
    )  # fmt: skip

    def progress(task: str, record: TaskRoundRecord) -> None:
        show(bar, task=task, evals=record.eval_episodes, ok=record.successes, demos=record.demos_added)

    ctx = RoundContext(
        suite,
        dataset,
        executor,
        cfg.collector.expert_name(suite),
        round_index,
        cfg.seed,
        source="plan" if cfg.plan_only else strategy.name,
        journal=journal,
        commit_every=cfg.commit_every,
        policy_path=str(cfg.policy.path) if needs_policy else None,
        commit_by_task=strategy.commits_by_task,
        takeover=cfg.takeover if cfg.demo_start == "takeover" else None,
        keep_successes=cfg.keep_successes,
        on_progress=progress,
        on_task_done=lambda task: bar.update(1),
    )
    if cfg.plan_only:
        return plan(cfg, suite, ctx, strategy)

    finish_stale_journals(root)
    if round_index in ledger_rounds(root):
        print(f"round {round_index} is already complete (meta/adademo/rounds.jsonl)")
        return []
    ctx.resume_commits()  # what a stopped run committed to the journal is merged first
    started = journal.of_type("start")
    decided = strategy.start(ctx, started[0] if started else None)
    # The evaluation batch decides which states a round evaluates together (and their outcomes' seeds) and the
    # expert its demonstrations: fixed for the round, except in one journaled before they were recorded.
    expert = cfg.collector.to_dict()
    recorded_since = {"eval_batch_size": ctx.batch_size, "collector": expert}
    if started:
        recorded_since = {k: v for k, v in recorded_since.items() if k in started[0]}
    journal.start(
        {
            "strategy": strategy.name,
            **decided,
            "seed": cfg.seed,
            "policy_path": str(Path(cfg.policy.path).resolve()) if needs_policy else None,
            **journaled_round_settings(cfg),
            **recorded_since,
        },
        field_defaults=config_field_defaults({"collector": expert}),
    )
    started_at = time.perf_counter()
    records = strategy.expand(ctx)
    ctx.close()  # every demonstration the round committed is in the dataset
    if not strategy.commits_by_task:  # one loop over the whole round
        bar.update(len(suite.tasks))
        share_round_time(records, time.perf_counter() - started_at, journal)
    bar.close()
    for record in records:
        record.collector = expert
        ctx.evaluation_cost(record.task, record)
        record.policy_episodes_kept = len(ctx.kept_successes(record.task))
        record.wall_seconds = round(journal.seconds(record.task), 3)
    check_ledger_matches_dataset(root, round_index, records)
    append_ledger(root, records)
    if on_ledger_written is not None:
        on_ledger_written(round_index)
    journal.finish()
    remove_shard_folders(root)  # what is left there is a killed worker's unfinished shard
    print(format_round_table(records))
    merged = ctx.merged_shards
    by_workers = f" ({merged} written by the Ray workers, merged here)" if merged else ""
    kept = sum(r.policy_episodes_kept for r in records)
    kept_text = f" and {kept} successful policy rollouts" if cfg.keep_successes else ""
    print(
        f"round {round_index}: {sum(r.demos_added for r in records)} new episodes{kept_text} in {root}{by_workers}"
    )
    return records


def share_round_time(records: list[TaskRoundRecord], seconds: float, journal: RoundJournal) -> None:
    """A round-wide loop journals its time per task in proportion to each task's env steps."""
    steps = {
        r.task: r.collection_env_steps + sum(e["steps"] for e in journal.evaluations(r.task).values())
        for r in records
    }
    total = sum(steps.values()) or 1
    journal.append(*({"type": "time", "task": t, "seconds": seconds * n / total} for t, n in steps.items()))


def check_ledger_matches_dataset(root: Path, round_index: int, records: list[TaskRoundRecord]) -> None:
    eps = read_episode_metadata(root)
    this_round = eps[eps[COL_ROUND] == round_index]
    by_policy = this_round[COL_SOURCE] == POLICY_SOURCE
    demos, kept = this_round[~by_policy].groupby("task").size(), this_round[by_policy].groupby("task").size()
    for r in records:
        if int(demos.get(r.task, 0)) != r.demos_added or int(kept.get(r.task, 0)) != r.policy_episodes_kept:
            raise RuntimeError(
                f"internal error: round {round_index} {r.task}: ledger {r.demos_added} demos and "
                f"{r.policy_episodes_kept} policy episodes, dataset {int(demos.get(r.task, 0))} and "
                f"{int(kept.get(r.task, 0))}"
            )
