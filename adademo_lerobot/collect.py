"""Expert demonstrations from fresh random initial states: the initial collection (`adademo-collect`)."""

from __future__ import annotations

import time
from pathlib import Path

from tqdm import tqdm

from adademo_lerobot.collectors.base import ExpertCollector
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.ledger import TaskRoundRecord
from adademo_lerobot.strategies.base import RoundContext, fresh_state_seed  # noqa: F401  (re-exported)
from adademo_lerobot.suites.base import TaskSuite


def collect_fresh(
    suite: TaskSuite,
    collector: ExpertCollector,
    dataset: DemoDataset,
    demos_per_task: dict[str, int],
    seed: int,
    round_index: int,
    source: str,
    commit_every: int = 10,
    desc: str = "collecting",
) -> dict[str, TaskRoundRecord]:
    """Collect `demos_per_task[task]` demonstrations of each task from fresh seeded initial states.

    Resumable: states already in the dataset for this round (same seed) count as done, and the draw
    sequence is deterministic, so an interrupted run completes to the same dataset.
    """
    records: dict[str, TaskRoundRecord] = {}
    with tqdm(total=sum(demos_per_task.values()), desc=desc, unit="demo", dynamic_ncols=True) as bar:
        done_before = 0

        def progress(task: str, record: TaskRoundRecord) -> None:
            bar.n = done_before + record.demos_added
            bar.set_postfix(task=task, expert_failures=record.expert_failures, refresh=False)
            bar.refresh()

        ctx = RoundContext(suite, dataset, collector, round_index, seed, source, commit_every=commit_every,
                           on_progress=progress)
        for task, wanted in demos_per_task.items():
            started = time.perf_counter()
            record = ctx.new_record(task, source)
            record.demos_per_task, record.target_successes, record.max_demos_per_task = wanted, None, None
            ctx.collect_from_fresh_states(task, wanted, record)
            ctx.flush(task, started)
            record.wall_seconds = time.perf_counter() - started
            records[task] = record
            done_before += record.demos_added
    return records


def format_collection_table(records: dict[str, TaskRoundRecord]) -> str:
    rows = [("task", "demos", "expert failures", "env steps")]
    for r in records.values():
        rows.append((r.task, f"{r.demos_added}/{r.demos_per_task}", str(r.expert_failures), str(r.collection_env_steps)))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    for r in records.values():
        if r.demos_added < r.demos_per_task:
            lines.append(
                f"note: {r.task} has {r.demos_added} of {r.demos_per_task} demos: the expert failed on "
                f"{r.expert_failures} initial states (after all attempts); raise --collector.max_attempts or accept fewer"
            )
    return "\n".join(lines)


def run_collect(cfg) -> dict[str, TaskRoundRecord]:
    """`adademo-collect`: the initial dataset (round 0, source `initial`)."""
    from adademo_lerobot.collectors.base import make_collector
    from adademo_lerobot.dataset.store import load_suite_config
    from adademo_lerobot.errors import AdaDemoError
    from adademo_lerobot.suites.base import make_suite

    # Validate everything before touching the disk.
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (the folder of the LeRobot dataset to create)")
    if cfg.episodes_per_task < 1:
        raise AdaDemoError(f"--episodes_per_task must be >= 1, got {cfg.episodes_per_task}")
    suite = make_suite(cfg.suite)
    collector = make_collector(cfg.collector, suite)
    root = Path(cfg.dataset.root)
    exists = (root / "meta" / "info.json").exists()
    if exists and cfg.resume:
        dataset = DemoDataset.open(cfg.dataset.repo_id, root)
        check_same_suite(load_suite_config(root), suite.config)
    else:
        DemoDataset.check_new_root(root)
        dataset = DemoDataset(cfg.dataset.repo_id, root, suite.config)
    start = time.perf_counter()
    summaries = collect_fresh(
        suite, collector, dataset, {t: cfg.episodes_per_task for t in suite.tasks}, cfg.seed,
        round_index=0, source="initial", commit_every=cfg.commit_every, desc="initial demos",
    )
    print(format_collection_table(summaries))
    print(f"dataset: {root} ({time.perf_counter() - start:.1f} s)")
    return summaries


def check_same_suite(stored, requested) -> None:
    from adademo_lerobot.errors import AdaDemoError

    a, b = stored.to_dict(), requested.to_dict()
    diffs = [f"{k}: dataset has {a.get(k)!r}, command has {b.get(k)!r}" for k in sorted(set(a) | set(b))
             if a.get(k) != b.get(k)]
    if diffs:
        raise AdaDemoError("the dataset was collected with another suite configuration (" + "; ".join(diffs) + ")")
