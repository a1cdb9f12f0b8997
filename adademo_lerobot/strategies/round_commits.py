"""How a round's demonstrations reach the dataset (`OrderedAppender`): in the order a sequential round would add
them whatever the executor, in commits of `--commit_every`; with Ray workers writing shards, each commit a journal
line naming them, merged 100 at a time while the round goes on (`merge_journaled_shards` after a stop)."""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path

from adademo_lerobot.core.episodes import Demonstration
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import COL_SEED
from adademo_lerobot.dataset.ledger import RoundJournal
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.shard_merge import MergePlan, ShardMerger, prepare
from adademo_lerobot.dataset.shards import Shard, read_shard, remove_shards
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.executors import Lazy, Pending
from adademo_lerobot.suites.base import TaskSuite

# With a journal, the workers' shards a commit names are merged into the dataset this many at a time and at the end
# of the round: a commit is then a journal line naming its shards (synced), and a merge's fixed cost (~9 ms of
# file-system work for its transaction, whatever its size) is paid once per hundred demonstrations instead of once
# per commit. The merge's files are written by a worker (`Executor.prepare_merge`) while the round goes on; the
# driver moves them in (benchmarks/results/loop_speed.md). A stopped round merges what its journal committed when it
# resumes.
MERGE_EVERY = 100


class OrderedAppender:
    """Commits demonstrations to the dataset in the order a sequential round would: task by task in the suite's
    order, each task's demos in the order its loop asked for them, a commit every `commit_every` demos and at
    the end of each task. Tasks whose loops run at once (Ray executor) hold their demos until every earlier task
    is done, so the dataset's episode order does not depend on the executor.

    With a `journal`, a commit of shards (Ray workers wrote the demonstrations) is a journal line naming them at
    their episode indices; they are merged `MERGE_EVERY` at a time and by `close()`, and after a stop by
    `merge_journaled_shards`. A merge's files are written by `prepare_merge` (a Ray worker) while the round goes
    on, and committed here once written, in order. Without a journal (or for demonstrations in memory) a commit is
    a write of the dataset."""

    def __init__(
        self,
        dataset: DemoDataset,
        suite: TaskSuite,
        round_index: int,
        source: str,
        collector: str,
        commit_every: int,
        tasks: list[str],
        journal: RoundJournal | None = None,
        prepare_merge: Callable[[MergePlan], Pending] | None = None,
    ):
        self.dataset, self.suite, self.journal = dataset, suite, journal
        self.prepare_merge = prepare_merge  # who writes a merge's files (a Ray worker); None: this process
        self.round_index, self.source, self.collector = round_index, source, collector
        self.commit_every = max(1, commit_every)
        self.by_task = tasks is not None  # None: commit in the order demos arrive (one loop over all tasks)
        self.order = list(tasks or [])
        self._head = 0  # index in `order` of the first unfinished task
        self._held: dict[str, list[Demonstration]] = {t: [] for t in self.order}
        self._finished: set[str] = set()
        self._buffer: list[Demonstration | Shard] = []
        self._unmerged: list[Shard] = []  # committed to the journal, not merged yet
        self._merging: deque[tuple[MergePlan, list[Shard], Pending]] = deque()  # planned, being prepared
        self._next_episode: int | None = None  # the episode index the next committed shard will have
        self._lock = threading.RLock()
        self.merged_shards = 0  # demonstrations the workers wrote themselves (merged, not appended)
        self._merger = ShardMerger(dataset)

    def add(self, task: str, demo: Demonstration) -> None:
        with self._lock:
            if not self.by_task or (self._head < len(self.order) and task == self.order[self._head]):
                self._buffer.append(demo)
                if len(self._buffer) >= self.commit_every:
                    self.flush()
            else:
                self._held[task].append(demo)

    def finish(self, task: str) -> None:
        with self._lock:
            if not self.by_task:
                self.flush()
                return
            self._finished.add(task)
            while self._head < len(self.order) and self.order[self._head] in self._finished:
                self.flush()  # the end of a task is a commit point
                self._head += 1
                if self._head < len(self.order):
                    for demo in self._held.pop(self.order[self._head]):
                        self.add(self.order[self._head], demo)

    def flush(self) -> None:
        """A commit of what is buffered."""
        with self._lock:
            batch, self._buffer = self._buffer, []
            if not batch:
                return
            if self.journal is not None and isinstance(batch[0], Shard):
                if self._next_episode is None:
                    self._next_episode = int(read_info(self.dataset.root)["total_episodes"])
                self.journal.append(
                    shards_entry(self._next_episode, batch, self.dataset.root), sync=True
                )  # the commit
                self._next_episode += len(batch)
                self._unmerged += batch
                if len(self._unmerged) >= MERGE_EVERY:
                    self._start_merge()
                self._commit_merges(wait=False)
                return
            if self.journal is not None:
                self.journal.sync()  # the entries that count these demonstrations are durable before they are
            if isinstance(batch[0], Shard):
                self._merge(batch)
            else:
                self.dataset.append(self.suite, batch, self.round_index, self.source, self.collector)

    def close(self) -> None:
        """Merge every committed shard (the end of a round)."""
        with self._lock:
            self.flush()
            self._start_merge()
            self._commit_merges(wait=True)

    def _start_merge(self) -> None:
        if self._unmerged:
            shards, self._unmerged = self._unmerged, []
            plan = self._merger.plan(shards, self.round_index, self.source, self.collector)
            here = self.prepare_merge is None
            prepared = Lazy(lambda: prepare(plan, shards)) if here else self.prepare_merge(plan)
            self._merging.append((plan, shards, prepared))

    def _commit_merges(self, wait: bool) -> None:
        """Commit the prepared merges, in order (all of them, waiting, with `wait`)."""
        while self._merging and (wait or self._merging[0][2].ready()):
            plan, shards, prepared = self._merging.popleft()
            try:
                self._merger.commit(plan, prepared.result())
            except BaseException:  # the round stops; what the journal committed is merged when it resumes
                self._merger.abandon()
                self._merging.clear()
                raise
            remove_shards(shards)
            self.merged_shards += len(shards)

    def _merge(self, shards: list[Shard]) -> None:
        """A merge of these shards now, in this process."""
        if shards:
            self._merger.merge(shards, self.round_index, self.source, self.collector)
            remove_shards(shards)
            self.merged_shards += len(shards)


def shards_entry(at: int, shards: list[Shard], root: Path) -> dict:
    """The journal's commit of workers' shards: their paths, tasks and seeds, from episode index `at` on. A path
    is relative to the folder that holds the dataset `root` and its shard folders, so that a dataset moved with them
    between a stop and its resume (to a bigger disk, say) still finds them."""
    parent = _shards_base(root)
    return {
        "type": "shards",
        "at": at,
        "shards": [[_relative_under(parent, s.path), s.task, s.seed] for s in shards],
    }


def _shards_base(root: Path) -> str:
    """The folder a journal's shard paths are relative to: the one holding the dataset and its shard folders."""
    return os.path.dirname(os.path.abspath(root))


def _relative_under(parent: str, path: str) -> str:
    path = os.path.abspath(path)
    return os.path.relpath(path, parent) if path.startswith(parent + os.sep) else path


def merge_journaled_shards(appender: OrderedAppender) -> int:
    """Merge the shards a stopped run of this round committed to its journal but had not merged, in their order,
    up to the first that is not whole (a machine crash may lose a shard its journal names: that demonstration
    and those after it are collected again, the same). Returns how many were merged."""
    dataset, journal = appender.dataset, appender.journal
    committed: dict[int, tuple[str, str, int]] = {}  # episode index -> (folder, task, seed)
    for entry in journal.of_type("shards"):
        # A later run's commit replaces what an earlier one committed from the same index on (lost shards).
        committed = {i: s for i, s in committed.items() if i < entry["at"]}
        committed |= {entry["at"] + k: tuple(s) for k, s in enumerate(entry["shards"])}
    total = int(read_info(dataset.root)["total_episodes"])
    merged_before = sorted(i for i in committed if i < total)
    if merged_before:
        eps = read_episode_metadata(dataset.root)
        for i in merged_before:
            _, task, seed = committed[i]
            if (eps.loc[i, "task"], int(eps.loc[i, COL_SEED])) != (task, seed):
                raise AdaDemoError(
                    f"the dataset {dataset.root} changed since round {journal.round_index} stopped: its episode "
                    f"{i} is {eps.loc[i, 'task']} seed {int(eps.loc[i, COL_SEED])}, the round's journal committed "
                    f"{task} seed {seed} there; restore the dataset as the round left it, or remove "
                    f"{journal.path} to run the round again from its start"
                )
    shards, parent = [], Path(_shards_base(dataset.root))
    while total + len(shards) in committed:
        # Relative to the dataset's parent folder (an absolute path, an older journal's, stays as it is).
        shard = read_shard(parent / committed[total + len(shards)][0])
        if shard is None:
            break
        shards.append(shard)
    for begin in range(0, len(shards), MERGE_EVERY):
        appender._merge(shards[begin : begin + MERGE_EVERY])
    return len(shards)
