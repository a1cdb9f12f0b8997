"""What every expansion strategy gets (`RoundContext`) and provides (`ExpansionStrategy`).

The context owns the side effects a round needs, each journaled so an interrupted round resumes exactly:
evaluating the policy on initial states, asking the expert for a demonstration from one state, and appending
demonstrations to the dataset in crash-safe commits.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from adademo_lerobot.collectors.base import ExpertCollector
from adademo_lerobot.dataset.layout import COL_ROUND, COL_SEED
from adademo_lerobot.dataset.store import BufferedAppender, DemoDataset
from adademo_lerobot.ledger import RoundJournal
from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.seeds import fresh_state_seed
from adademo_lerobot.suites.base import TaskSuite

# A task whose expert keeps failing stops after this many fresh initial states per requested demo.
MAX_DRAWS_PER_DEMO = 3


def planned_demos(target_successes: int, success_rate: float, cap: int) -> int:
    """The paper's N_k = E / SR_k - E, capped at CAP (SR_k = 0 gets CAP)."""
    if success_rate <= 0:
        return cap
    return min(cap, max(0, math.ceil(target_successes / success_rate - target_successes - 1e-9)))


@dataclass
class Outcome:
    """The policy's result from one initial state (the state is the seed's)."""

    seed: int
    success: bool


class Evaluator(Protocol):
    """Runs the policy from the initial states of `seeds` (see `evaluation.BatchedEvaluator`)."""

    batch_size: int

    def run(self, task: str, seeds: list[int]) -> list: ...


@dataclass
class RoundContext:
    suite: TaskSuite
    dataset: DemoDataset
    collector: ExpertCollector
    round_index: int
    seed: int
    source: str
    evaluator: Evaluator | None = None
    journal: RoundJournal | None = None
    target_successes: int = 10
    max_demos_per_task: int = 50
    demos_per_task: int = 10
    max_eval_episodes_per_task: int = 200
    plan_episodes_per_task: int = 20
    commit_every: int = 10
    policy_path: str | None = None
    on_progress: Callable[[str, TaskRoundRecord], None] | None = None
    _committed: dict[str, set[int]] = field(default_factory=dict)
    _appender: BufferedAppender | None = None

    def __post_init__(self) -> None:
        self._appender = BufferedAppender(
            self.dataset, self.suite, self.round_index, self.source, self.collector.name, self.commit_every
        )
        if (self.dataset.root / "meta" / "info.json").exists():
            eps = self.dataset.episodes()
            this_round = eps[eps[COL_ROUND] == self.round_index]
            for task, seeds in this_round.groupby("task")[COL_SEED]:
                self._committed[task] = set(seeds.astype(np.int64).tolist())

    def new_record(self, task: str, strategy: str) -> TaskRoundRecord:
        return TaskRoundRecord(
            self.round_index,
            task,
            strategy,
            self.target_successes,
            self.max_demos_per_task,
            self.demos_per_task,
            self.policy_path,
        )

    # -- evaluation -------------------------------------------------------------------------------------
    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        """Policy outcomes from these seeds' initial states; journaled outcomes are reused, not re-run."""
        known = self.journal.evaluations(task) if self.journal else {}
        todo = [s for s in seeds if s not in known]
        if todo:
            if self.evaluator is None:
                raise RuntimeError("this strategy has no policy to evaluate")
            fresh = {
                r.seed: {"type": "eval", "task": task, "seed": r.seed, "success": r.success, "steps": r.steps}
                for r in self.evaluator.run(task, todo)
            }
            if self.journal:
                self.journal.append(*(fresh[s] for s in todo))  # also indexes them into `known`
            else:
                known = {**known, **fresh}
        return [Outcome(s, bool(known[s]["success"])) for s in seeds]

    def evaluation_cost(self, task: str, record: TaskRoundRecord) -> None:
        evals = self.journal.evaluations(task) if self.journal else {}
        record.eval_episodes_run = len(evals)
        record.eval_env_steps = sum(e["steps"] for e in evals.values())

    # -- collection -------------------------------------------------------------------------------------
    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        """Ask the expert for a demonstration from exactly this seed's initial state (at most once a round)."""
        if seed in self._committed.get(task, set()):
            record.demos_added += 1  # committed before an interruption
            return True
        failures = self.journal.expert_failures(task) if self.journal else {}
        if seed in failures:
            self._count_expert_failure(record, failures[seed])
            return False
        result = self.collector.collect(task, self.suite.sample_initial_state(task, seed), seed)
        record.collection_env_steps += result.env_steps
        if result.demonstration is not None:
            self._appender.add(result.demonstration)
            self._committed.setdefault(task, set()).add(seed)
            record.demos_added += 1
            return True
        entry = {
            "type": "expert_failure",
            "task": task,
            "seed": int(seed),
            "attempts": result.attempts,
            "steps": result.env_steps,
            "initial_state": result.initial_state.tolist(),
        }
        if self.journal:
            self.journal.append(entry)
        self._count_expert_failure(record, entry, count_steps=False)
        return False

    @staticmethod
    def _count_expert_failure(record: TaskRoundRecord, entry: dict, count_steps: bool = True) -> None:
        record.expert_failures += 1
        if count_steps:
            record.collection_env_steps += entry["steps"]
        record.expert_failed_states.append(
            {"seed": entry["seed"], "initial_state": entry["initial_state"], "attempts": entry["attempts"]}
        )

    def collect_from_fresh_states(self, task: str, n: int, record: TaskRoundRecord) -> None:
        """n demonstrations from fresh random initial states (no evaluation): Uniform and ablation A."""
        for draw in range(n * MAX_DRAWS_PER_DEMO):
            if record.demos_added >= n:
                break
            self.collect_demo(task, fresh_state_seed(self.seed, self.round_index, task, draw), record)
            self.progress(task, record)

    def progress(self, task: str, record: TaskRoundRecord) -> None:
        if self.on_progress is not None:
            self.on_progress(task, record)

    def flush(self, task: str, started: float) -> None:
        """Commit buffered demonstrations and journal the time spent on this task."""
        self._appender.flush()
        if self.journal:
            self.journal.append({"type": "time", "task": task, "seconds": time.perf_counter() - started})


class ExpansionStrategy(Protocol):
    name: str
    needs_policy: bool

    def expand_task(self, ctx: RoundContext, task: str) -> TaskRoundRecord:
        """Add this round's demonstrations for one task and account for them."""
