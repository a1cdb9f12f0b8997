"""The books a round keeps, the same for a simulated round (`base.RoundContext`) and a person's on a robot
(`record.PersonRound`), the two contexts of Algorithm 1's inner loop (`algorithm.InnerLoop`): the ledger's record of
a task, the journal (every answer is journaled before it is acted on), which failed states the round has answered
already (after a stop: the demonstrations in the dataset, and the journaled expert failures) and what each answer
counts in the task's record.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from adademo_lerobot.core.episodes import Demonstration, TaskRoundRecord
from adademo_lerobot.dataset.layout import COL_ROUND, COL_SEED, COL_SOURCE, POLICY_SOURCE
from adademo_lerobot.dataset.ledger import RoundJournal
from adademo_lerobot.dataset.metadata import has_dataset, read_episode_metadata
from adademo_lerobot.dataset.shards import Shard


def demo_entry(task: str, seed: int, demo: Demonstration | Shard, steps: int) -> dict:
    """The journal's entry for a demonstration, in memory or in a worker's shard (a correction's carries its
    start step): `steps` is what it cost (the expert's env steps, every attempt; a person's frames)."""
    entry = {"type": "demo", "task": task, "seed": int(seed), "steps": int(steps), "frames": demo.num_frames}
    if demo.is_correction:
        entry["start_step"] = demo.start_step
    return entry


def count_demo(record: TaskRoundRecord, entry: dict | None) -> None:
    """A demonstration in the task's record, with its journaled cost (None: its entry was lost)."""
    record.demos_added += 1
    if entry is not None:
        record.collection_env_steps += entry["steps"]
        record.demo_frames += entry.get("frames", 0)
        record.corrections += entry.get("start_step") is not None
        record.takeover_failures += entry.get("takeover_failed", False)


def count_expert_failure(record: TaskRoundRecord, entry: dict) -> None:
    """A failed state the expert (or the person) gave no demonstration for, in the task's record."""
    record.expert_failures += 1
    record.collection_env_steps += entry.get("steps", 0)
    record.takeover_failures += entry.get("takeover_failed", False)
    failed = {
        "seed": entry["seed"],
        "initial_state": entry.get("initial_state"),
        "attempts": entry["attempts"],
    }
    if "start_step" in entry:
        failed["start_step"] = entry["start_step"]
    record.expert_failed_states.append(failed)


class JournaledRound:
    """The bookkeeping both round contexts share. A subclass sets `round_index`, `journal`, `policy_path`, `_lock`
    and `_committed` (`committed_demos(root, round_index)` at its start)."""

    round_index: int
    journal: RoundJournal | None
    policy_path: str | None
    _committed: dict[str, set[int]]
    _lock: threading.RLock

    def new_record(
        self,
        task: str,
        strategy: str,
        target_successes: int | None = None,
        cap: int | None = None,
        demos: int | None = None,
    ) -> TaskRoundRecord:
        """The ledger's record of `task` in this round, with the strategy's E, CAP and N (None where unused)."""
        return TaskRoundRecord(
            self.round_index, task, strategy, target_successes, cap, demos, self.policy_path
        )

    # Whether each entry is fsync'd as it is written; a simulated round syncs the journal before each dataset
    # commit instead (`RoundContext`: ~0.3 ms per demonstration less on the driver).
    sync_each_entry: bool = True

    def _journal(self, *entries: dict) -> None:
        if self.journal:
            with self._lock:
                self.journal.append(*entries, sync=self.sync_each_entry)

    def known_evaluations(self, task: str) -> dict[int, dict]:
        """The task's journaled evaluations this round, by seed (a copy)."""
        return dict(self.journal.evaluations(task)) if self.journal else {}

    def answered(self, task: str) -> set[int]:
        """Failed states of `task` this round has answered: a demonstration in the dataset, or none from the
        expert (journaled)."""
        return self._committed.get(task, set()) | set(
            self.journal.expert_failures(task) if self.journal else ()
        )

    def reuse_answer(self, task: str, seed: int, record: TaskRoundRecord) -> bool | None:
        """A failure this round answered before (a rerun after a stop), counted from the journal: True for a
        demonstration, False when the expert gave none; None when it is not answered yet."""
        if seed in self._committed.get(task, set()):
            count_demo(record, self.journal.demos(task).get(seed) if self.journal else None)
            return True
        failures = self.journal.expert_failures(task) if self.journal else {}
        if seed in failures:
            count_expert_failure(record, failures[seed])
            return False
        return None

    def store_answer(
        self, task: str, entry: dict, record: TaskRoundRecord, append: Callable[[], None] | None = None
    ) -> bool:
        """A failure's answer: journaled first (a `demo` or an `expert_failure` entry), then the demonstration is
        appended (`append()`) and the answer counted in the task's record. True for a demonstration."""
        self._journal(entry)
        if entry["type"] != "demo":
            count_expert_failure(record, entry)
            return False
        append()
        with self._lock:
            self._committed.setdefault(task, set()).add(entry["seed"])
        count_demo(record, entry)
        return True

    def evaluation_cost(self, task: str, record: TaskRoundRecord) -> None:
        """The ledger's count of every policy episode the round ran for `task` (also those past its stopping
        point, before a stop) and their env steps."""
        evals = self.journal.evaluations(task) if self.journal else {}
        record.eval_episodes_run = len(evals)
        record.eval_env_steps = sum(e["steps"] for e in evals.values())


def committed_demos(root: Path, round_index: int) -> dict[str, set[int]]:
    """This round's demonstrations already in the dataset, by task (their seeds): what survived a stop."""
    return committed_answers(root, round_index)[0]


def committed_answers(root: Path, round_index: int) -> tuple[dict[str, set[int]], dict[str, set[int]]]:
    """`committed_demos`, and this round's kept policy successes (`--keep_successes`) by task, from one read."""
    if not has_dataset(root):
        return {}, {}
    eps = read_episode_metadata(root)
    this_round = eps[eps[COL_ROUND] == round_index]
    by_policy = this_round[COL_SOURCE] == POLICY_SOURCE

    def seeds_by_task(rows) -> dict[str, set[int]]:
        return {task: set(seeds.astype(np.int64).tolist()) for task, seeds in rows.groupby("task")[COL_SEED]}

    return seeds_by_task(this_round[~by_policy]), seeds_by_task(this_round[by_policy])
