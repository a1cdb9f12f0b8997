"""Expert demonstrations from fresh random initial states: the initial collection (`adademo-collect`)."""

from __future__ import annotations

import time
from pathlib import Path

from tqdm import tqdm

from adademo_lerobot.collectors import CollectorConfig, ScriptedCollectorConfig
from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.progress import show
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.imitability import disagreement_notes
from adademo_lerobot.dataset.metadata import check_same_suite, has_dataset, load_suite_config
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.executors import ExecutionArgs, Executor, make_executor
from adademo_lerobot.strategies.round_context import RoundContext
from adademo_lerobot.suites import TaskSuite, make_suite


def collect_fresh(
    suite: TaskSuite,
    dataset: DemoDataset,
    demos_per_task: dict[str, int],
    seed: int,
    round_index: int,
    source: str,
    collector_config: CollectorConfig | None = None,
    executor: Executor | None = None,
    commit_every: int = 10,
    desc: str = "collecting",
) -> dict[str, TaskRoundRecord]:
    """Collect `demos_per_task[task]` demonstrations of each task from fresh seeded initial states, with the
    given expert (default: the suite's scripted one) on `executor` (default: this process).

    Resumable: states already in the dataset for this round (same seed) count as done, and the draw
    sequence is deterministic, so an interrupted run completes to the same dataset.
    """
    collector_config = collector_config or ScriptedCollectorConfig()
    own_executor = executor is None
    if own_executor:
        executor = make_executor(ExecutionArgs(torch_threads=1), suite, collector_config, batch_size=1)
    done: dict[str, int] = {}
    try:
        with tqdm(total=sum(demos_per_task.values()), desc=desc, unit="demo", dynamic_ncols=True) as bar:

            def progress(task: str, record: TaskRoundRecord) -> None:
                done[task] = record.demos_added
                bar.n = sum(done.values())
                show(bar, task=task, expert_failures=record.expert_failures)

            ctx = RoundContext(
                suite,
                dataset,
                executor,
                collector_config.expert_name(suite),
                round_index,
                seed,
                source,
                commit_every=commit_every,
                on_progress=progress,
            )

            def collect_task(task: str) -> TaskRoundRecord:
                started = time.perf_counter()
                record = ctx.new_record(task, source)
                record.demos_per_task, record.target_successes, record.max_demos_per_task = (
                    demos_per_task.get(task, 0),
                    None,
                    None,
                )
                ctx.collect_from_fresh_states(task, record.demos_per_task, record)
                record.wall_seconds = time.perf_counter() - started
                return record

            records = ctx.run_tasks(collect_task)
    finally:
        if own_executor:
            executor.close()
    return {r.task: r for r in records if r.task in demos_per_task}


def format_collection_table(records: dict[str, TaskRoundRecord], root: Path) -> str:
    """The collection's table per task, with a note for a task short of demonstrations and for one whose
    demonstrations (in the dataset at `root`) disagree with each other."""
    rows = [
        (r.task, f"{r.demos_added}/{r.demos_per_task}", r.expert_failures, r.collection_env_steps)
        for r in records.values()
    ]
    lines = [table(["task", "demos", "expert failures", "env steps"], rows)]
    for r in records.values():
        if r.demos_added < r.demos_per_task:
            lines.append(
                f"note: {r.task} has {r.demos_added} of {r.demos_per_task} demos: the expert failed on "
                f"{r.expert_failures} initial states (after all attempts); raise --collector.max_attempts or accept fewer"
            )
    if has_dataset(root):
        lines += disagreement_notes(root, list(records))
    return "\n".join(lines)


def collect_initial_demos(
    suite: TaskSuite,
    dataset: DemoDataset,
    per_task: int,
    seed: int,
    collector_config,
    executor,
    commit_every: int,
) -> dict[str, TaskRoundRecord]:
    """Round 0: `per_task` demos of every task from fresh initial states (adademo-collect and adademo-run)."""
    return collect_fresh(
        suite,
        dataset,
        dict.fromkeys(suite.tasks, per_task),
        seed,
        round_index=0,
        source="initial",
        collector_config=collector_config,
        executor=executor,
        commit_every=commit_every,
        desc="initial demos",
    )


def run_collect(cfg) -> dict[str, TaskRoundRecord]:
    """`adademo-collect`: the initial dataset (round 0, source `initial`)."""
    # Validate everything before touching the disk.
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (the folder of the LeRobot dataset to create)")
    if cfg.episodes_per_task < 1:
        raise AdaDemoError(f"--episodes_per_task must be >= 1, got {cfg.episodes_per_task}")
    cfg.validate_execution()
    suite = make_suite(cfg.suite)
    cfg.collector.validate(suite)
    root = Path(cfg.dataset.root)
    with exclusive_use(root, "adademo-collect"):  # one command at a time on a dataset
        if has_dataset(root) and cfg.resume:
            check_same_suite(load_suite_config(root), suite.config)
            dataset = DemoDataset.open(cfg.dataset.repo_id, root)
            check_dataset_integrity(root)
        else:
            DemoDataset.check_new_root(root)
            dataset = DemoDataset(cfg.dataset.repo_id, root, suite.config)
        start = time.perf_counter()
        executor = make_executor(cfg, suite, cfg.collector, batch_size=1)
        try:
            summaries = collect_initial_demos(
                suite, dataset, cfg.episodes_per_task, cfg.seed, cfg.collector, executor, cfg.commit_every
            )
        finally:
            executor.close()
        print(format_collection_table(summaries, root))
        print(f"dataset: {root} ({time.perf_counter() - start:.1f} s)")
    return summaries
