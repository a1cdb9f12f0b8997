"""What a strategy's round gets (`RoundContext`, the simulated round): the side effects a round needs, each
journaled so an interrupted round resumes exactly: evaluating the policy on initial states, asking the expert for
a demonstration from one state, and appending demonstrations to the dataset in crash-safe commits, in the order
the strategy asked for them (`round_commits.OrderedAppender`)."""

from __future__ import annotations

import shutil
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.episodes import EpisodeRecord, TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError, RoundAbortedError
from adademo_lerobot.core.seeds import fresh_state_seed
from adademo_lerobot.dataset.ledger import RoundJournal
from adademo_lerobot.dataset.metadata import has_dataset
from adademo_lerobot.dataset.shards import shard_folder
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.executors import Executor, Pending
from adademo_lerobot.strategies.bookkeeping import JournaledRound, committed_answers, demo_entry
from adademo_lerobot.strategies.round_commits import OrderedAppender, merge_journaled_shards
from adademo_lerobot.suites.base import TaskSuite, full_state_step

# A task whose expert keeps failing stops after this many fresh initial states per requested demo.
MAX_DRAWS_PER_DEMO = 3


def eval_entry(task: str, record: EpisodeRecord) -> dict:
    """The journal's entry for one evaluation (a failed one, with --demo_start=takeover, carries its takeover)."""
    entry = {
        "type": "eval",
        "task": task,
        "seed": record.seed,
        "success": record.success,
        "steps": record.steps,
    }
    if record.takeover_state is not None:
        entry |= {
            "takeover_step": record.takeover_step,
            "takeover_rule": record.takeover_rule,
            "takeover_state": record.takeover_state,
        }
    return entry


@dataclass
class Outcome:
    """The policy's result from one initial state (the state is the seed's)."""

    seed: int
    success: bool


@dataclass
class RoundContext(JournaledRound):
    """A simulated round (`algorithm.InnerLoop`): the policy evaluated and the expert run by the executor on the
    suite's initial states, demonstrations committed in order (`OrderedAppender`)."""

    suite: TaskSuite
    dataset: DemoDataset
    executor: Executor
    collector_name: str
    round_index: int
    seed: int
    source: str
    journal: RoundJournal | None = None
    commit_every: int = 10
    policy_path: str | None = None
    commit_by_task: bool = True  # False: one loop over all tasks commits demos in the order they arrive
    # --demo_start=takeover: demonstrations are corrections that start where the expert takes over the failed
    # rollout (this rule picks the step); None: from the failed episode's initial state (the paper).
    takeover: TakeoverArgs | None = None
    # --keep_successes: the round's successful rollouts are added to the dataset too (`adademo/source=policy`).
    keep_successes: bool = False
    on_progress: Callable[[str, TaskRoundRecord], None] | None = None
    on_task_done: Callable[[str], None] | None = None
    _committed: dict[str, set[int]] = field(default_factory=dict)
    _kept: dict[str, set[int]] = field(default_factory=dict)  # seeds of the successes kept, by task
    _pending: dict[tuple[str, int], Pending] = field(default_factory=dict)
    _takeover_states: dict[tuple[str, int], list[float]] = field(default_factory=dict)
    _appender: OrderedAppender | None = None
    _lock: threading.RLock = field(default_factory=threading.RLock)
    # Set when one task's loop failed: the others stop at their next evaluation or demonstration.
    _aborted: threading.Event = field(default_factory=threading.Event)
    # Env steps of the evaluations this context ran (not those reused from the journal).
    eval_env_steps: int = 0
    sync_each_entry = False  # the journal is synced at each commit (`OrderedAppender.flush`)

    def __post_init__(self) -> None:
        self._appender = OrderedAppender(
            self.dataset,
            self.suite,
            self.round_index,
            self.source,
            self.collector_name,
            self.commit_every,
            self.suite.tasks if self.commit_by_task else None,
            self.journal,
            self.executor.prepare_merge,
        )
        self._committed, self._kept = committed_answers(self.dataset.root, self.round_index)
        if self.journal is None:
            self._remove_stopped_shards()
        if self.executor.writes_shards and self.dataset.can_merge(self.suite):
            self.executor.shard_folder = str(shard_folder(self.dataset.root, self.round_index))

    def _remove_stopped_shards(self) -> None:
        # A stopped run's shards its journal did not commit: never merged, collected again.
        shutil.rmtree(shard_folder(self.dataset.root, self.round_index), ignore_errors=True)

    @property
    def corrects_failures(self) -> bool:
        return self.takeover is not None

    def resume_commits(self) -> None:
        """Before a round (re)starts: the shards a stopped run committed to the journal are merged (the round goes
        on from them), the others removed."""
        journaled = self.journal is not None and self.journal.exists() and has_dataset(self.dataset.root)
        if journaled and merge_journaled_shards(self._appender):
            self._committed, self._kept = committed_answers(self.dataset.root, self.round_index)
        self._remove_stopped_shards()

    def close(self) -> None:
        """The end of the round: every demonstration committed is in the dataset."""
        self._appender.close()

    def kept_successes(self, task: str) -> set[int]:
        """Seeds of the task's successful rollouts this round added to the dataset (--keep_successes)."""
        return self._kept.get(task, set())

    @property
    def merged_shards(self) -> int:
        """Demonstrations this round's workers wrote themselves, merged into the dataset (`dataset/shard_merge.py`)."""
        return self._appender.merged_shards

    @property
    def batch_size(self) -> int:
        """Episodes evaluated side by side in one unit of work (`--eval.batch_size`)."""
        return self.executor.batch_size

    @property
    def tasks(self) -> list[str]:
        return self.suite.tasks

    @property
    def root(self) -> Path:
        return self.dataset.root

    # -- evaluation -------------------------------------------------------------------------------------
    def _check_not_aborted(self) -> None:
        if self._aborted.is_set():
            raise RoundAbortedError

    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        """Policy outcomes from these seeds' initial states; journaled outcomes are reused, not re-run."""
        self._check_not_aborted()
        known = self.known_evaluations(task)
        todo = [s for s in seeds if s not in known]
        ran = {}
        if todo:
            ran = {
                r.seed: r
                for r in self.executor.evaluate(task, todo, self.takeover, self.keep_successes).result()
            }
            fresh = {s: eval_entry(task, r) for s, r in ran.items()}
            self._journal(*(fresh[s] for s in todo))
            with self._lock:
                self.eval_env_steps += sum(e["steps"] for e in fresh.values())
            known.update(fresh)
        for s in seeds:
            if self.takeover is not None and not known[s]["success"]:
                self._takeover_states[(task, s)] = known[s]["takeover_state"]
        if self.keep_successes:
            self._keep_successes(task, seeds, [s for s in seeds if known[s]["success"]], ran)
        return [Outcome(s, bool(known[s]["success"])) for s in seeds]

    def _keep_successes(
        self, task: str, seeds: list[int], successes: list[int], ran: dict[int, EpisodeRecord]
    ) -> None:
        """The successful rollouts added to the dataset, in seed order, each once a round. A success journaled
        before a stop whose rollout was not committed yet is run again, traced, in the batches it first ran in
        (these `seeds`, as the strategy asks again after a stop): the same episode to the last bit (an episode
        depends on the policy, its seed and its batch, `BatchedEvaluator.run`)."""
        kept = self._kept.setdefault(task, set())
        if any(s not in kept and s not in ran for s in successes):
            ran = {r.seed: r for r in self.executor.evaluate(task, seeds, None, True).result()}
        for s in successes:
            if s in kept:
                continue
            if ran[s].kept is None:  # the rerun failed where the journal says it succeeded: not reproducible
                raise AdaDemoError(
                    f"{task}, seed {s}: the journal says the policy succeeded, its rerun did not; the policy's "
                    "episodes are not reproducible here, so its successes cannot be kept after a stop: rerun "
                    "without --keep_successes"
                )
            self._appender.add(task, ran[s].kept)
            kept.add(s)

    # -- collection -------------------------------------------------------------------------------------
    def ask_expert(self, task: str, seeds: list[int]) -> None:
        """Start the expert on these states now (all at once with a Ray executor, a few per Ray call; the local
        executor still runs each when `collect_demo` needs it), skipping states this round already has an answer
        for."""
        done = self.answered(task)
        ask = list(dict.fromkeys(s for s in seeds if s not in done and (task, s) not in self._pending))
        for seed, pending in zip(ask, self._collect(task, ask), strict=True):
            self._pending[(task, seed)] = pending

    def _collect(self, task: str, seeds: list[int]) -> list[Pending]:
        units = [(seed, self._takeover_states.get((task, seed))) for seed in seeds]
        return self.executor.collect_many(task, units, self.takeover)

    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        """Ask the expert for a demonstration from exactly this seed's initial state (at most once a round)."""
        self._check_not_aborted()
        reused = self.reuse_answer(task, seed, record)
        if reused is not None:
            return reused
        pending = self._pending.pop((task, seed), None) or self._collect(task, [seed])[0]
        result = pending.result()
        demo = result.demonstration
        if demo is not None:
            entry = demo_entry(task, seed, demo, result.env_steps)
            if result.takeover_failed:
                entry["takeover_failed"] = True  # then a demonstration from the initial state
            return self.store_answer(task, entry, record, lambda: self._appender.add(task, demo))
        entry = {
            "type": "expert_failure",
            "task": task,
            "seed": int(seed),
            "attempts": result.attempts,
            "steps": result.env_steps,
            "initial_state": result.initial_state.tolist(),
        }
        if result.takeover_failed:
            entry["takeover_failed"] = True
            entry["start_step"] = full_state_step(self._takeover_states[(task, seed)])  # where it failed from
        return self.store_answer(task, entry, record)

    def collect_from_fresh_states(self, task: str, n: int, record: TaskRoundRecord) -> None:
        """n demonstrations from fresh random initial states (no evaluation): Uniform and ablation A.

        The expert is asked ahead for as many draws as demos are still missing, so a Ray executor runs them at
        once; the draws are consumed in order, so the same draws are used whatever the executor."""
        draws = [
            fresh_state_seed(self.seed, self.round_index, task, d) for d in range(n * MAX_DRAWS_PER_DEMO)
        ]
        for i, seed in enumerate(draws):
            if record.demos_added >= n:
                break
            self.ask_expert(task, draws[i : i + n - record.demos_added])
            self.collect_demo(task, seed, record)
            self.progress(task, record)

    def collect_from_next_fresh_state(self, task: str, draw: int, record: TaskRoundRecord) -> int:
        """One demonstration from the task's fresh initial states, starting at draw `draw` (the next draw after
        an expert failure, at most MAX_DRAWS_PER_DEMO); returns the draw to start from next time."""
        for d in range(draw, draw + MAX_DRAWS_PER_DEMO):
            if self.collect_demo(task, fresh_state_seed(self.seed, self.round_index, task, d), record):
                return d + 1
        return draw + MAX_DRAWS_PER_DEMO

    def progress(self, task: str, record: TaskRoundRecord) -> None:
        if self.on_progress is not None:
            with self._lock:
                self.on_progress(task, record)

    def finish_task(self, task: str, started: float) -> None:
        """Commit the task's demonstrations (in order) and journal the time spent on it."""
        self._appender.finish(task)
        self._journal({"type": "time", "task": task, "seconds": time.perf_counter() - started})

    def run_tasks(self, work: Callable[[str], TaskRoundRecord]) -> list[TaskRoundRecord]:
        """`work(task)` for every task of the suite; records in suite order. One task after the other with the
        local executor; side by side (one waiting thread per task, the episodes on the Ray workers) when the
        executor runs units in parallel. Either way every task's demos are committed in suite order."""

        def one(task: str) -> TaskRoundRecord:
            started = time.perf_counter()
            record = work(task)
            self.finish_task(task, started)
            if self.on_task_done is not None:
                with self._lock:
                    self.on_task_done(task)
            return record

        if not self.executor.parallel_tasks:
            return [one(task) for task in self.suite.tasks]
        with ThreadPoolExecutor(max_workers=len(self.suite.tasks), thread_name_prefix="adademo-task") as pool:
            futures = [pool.submit(one, task) for task in self.suite.tasks]
            try:
                wait(futures, return_when=FIRST_EXCEPTION)
            finally:  # a failed task (or Ctrl-C here) stops the others at their next step, never inside a commit
                if not all(f.done() and f.exception() is None for f in futures):
                    self._aborted.set()
                    self.executor.stop_waiting()  # a loop waiting for a long unit of the workers ends too
                    pool.shutdown(wait=True, cancel_futures=True)
            failed = [f.exception() for f in futures if not f.cancelled() and f.exception() is not None]
            first = next((e for e in failed if not isinstance(e, RoundAbortedError)), None)
            if first is not None:
                raise first
            return [f.result() for f in futures]
