"""Expert demonstrations from fresh random initial states (initial collection and the Uniform baseline)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from adademo_lerobot.collectors.base import CollectionResult, Demonstration, ExpertCollector
from adademo_lerobot.dataset.store import COL_ROUND, COL_SEED, DemoDataset
from adademo_lerobot.suites.base import TaskSuite, derive_seed

# A task whose expert keeps failing stops after this many fresh initial states per requested demo.
MAX_DRAWS_PER_DEMO = 3


def fresh_state_seed(seed: int, round_index: int, task: str, draw: int) -> int:
    """Seed of the `draw`-th fresh initial state of `task` in a round: the same seed gives the same states."""
    return derive_seed(seed, "fresh", round_index, task, draw)


@dataclass
class TaskCollectionSummary:
    task: str
    requested: int
    saved: int = 0
    already_present: int = 0
    expert_failures: int = 0  # initial states where every attempt failed: skipped, never saved
    failed_attempts: int = 0
    env_steps: int = 0
    failed_states: list[dict] = field(default_factory=list)

    @property
    def total(self) -> int:
        return self.saved + self.already_present


class BufferedAppender:
    """Buffers demonstrations and commits them to the dataset every `commit_every` episodes."""

    def __init__(self, dataset: DemoDataset, suite: TaskSuite, round_index: int, source: str, collector: str,
                 commit_every: int):
        self.dataset, self.suite = dataset, suite
        self.round_index, self.source, self.collector = round_index, source, collector
        self.commit_every = max(1, commit_every)
        self.buffer: list[Demonstration] = []
        self.written: list[int] = []

    def add(self, demo: Demonstration) -> None:
        self.buffer.append(demo)
        if len(self.buffer) >= self.commit_every:
            self.flush()

    def flush(self) -> None:
        if self.buffer:
            self.written += self.dataset.append(
                self.suite, self.buffer, self.round_index, self.source, self.collector
            )
            self.buffer = []


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
) -> dict[str, TaskCollectionSummary]:
    """Collect `demos_per_task[task]` demonstrations of each task from fresh seeded initial states.

    Resumable: states already in the dataset for this round (same seed) count as done, and the draw
    sequence is deterministic, so an interrupted run completes to the same dataset.
    """
    existing = dataset.episodes() if (dataset.root / "meta" / "info.json").exists() else None
    done_seeds: set[int] = set()
    if existing is not None and len(existing):
        done_seeds = set(existing.loc[existing[COL_ROUND] == round_index, COL_SEED].astype(np.int64).tolist())
    summaries = {task: TaskCollectionSummary(task, n) for task, n in demos_per_task.items()}
    appender = BufferedAppender(dataset, suite, round_index, source, collector.name, commit_every)
    total = sum(demos_per_task.values())
    with tqdm(total=total, desc=desc, unit="demo", dynamic_ncols=True) as bar:
        for task, wanted in demos_per_task.items():
            summary = summaries[task]
            for draw in range(wanted * MAX_DRAWS_PER_DEMO):
                if summary.total >= wanted:
                    break
                state_seed = fresh_state_seed(seed, round_index, task, draw)
                if state_seed in done_seeds:
                    summary.already_present += 1
                    bar.update(1)
                    continue
                result = collector.collect(task, suite.sample_initial_state(task, state_seed), state_seed)
                record_result(summary, result)
                if result.demonstration is not None:
                    appender.add(result.demonstration)
                    bar.update(1)
                bar.set_postfix(task=task, expert_failures=sum(s.expert_failures for s in summaries.values()))
    appender.flush()
    return summaries


def record_result(summary: TaskCollectionSummary, result: CollectionResult) -> None:
    summary.env_steps += result.env_steps
    summary.failed_attempts += result.failed_attempts
    if result.demonstration is not None:
        summary.saved += 1
    else:
        summary.expert_failures += 1
        summary.failed_states.append(
            {"seed": int(result.seed), "initial_state": result.initial_state.tolist(), "attempts": result.attempts}
        )


def format_collection_table(summaries: dict[str, TaskCollectionSummary]) -> str:
    rows = [("task", "demos", "new", "expert failures", "failed attempts")]
    for s in summaries.values():
        rows.append((s.task, f"{s.total}/{s.requested}", str(s.saved), str(s.expert_failures), str(s.failed_attempts)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    short = [s for s in summaries.values() if s.total < s.requested]
    for s in short:
        lines.append(
            f"note: {s.task} has {s.total} of {s.requested} demos: the expert failed on {s.expert_failures} initial "
            f"states (after all attempts); raise --collector.max_attempts or accept fewer"
        )
    return "\n".join(lines)


def run_collect(cfg) -> dict[str, TaskCollectionSummary]:
    """`adademo-collect`: the initial dataset (round 0, source `initial`)."""
    from pathlib import Path

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
