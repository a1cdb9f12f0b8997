"""`--executor=ray`: episodes run on Ray actors (this machine, or a cluster at `--ray.address`).

Each actor is an `EpisodeWorker`: it builds the suite's envs and the expert once and loads a round's policy once.
Units of work go to the actor with the fewest unfinished units. Ray restarts an actor whose process dies
(`kill -9`) and runs its unfinished units again (`max_restarts`, `max_task_retries`), so a round completes
with nothing lost or duplicated: units are deterministic, and the caller records each result once.

What Ray cannot replace ends the command within seconds with `LostRayClusterError` (one `error:` line; the rerun
resumes from the journal): a cluster whose GCS stops accepting connections (the head node, or a local Ray's
node, is gone), alive nodes without room left for every actor (a lost worker node), or an actor Ray gave up on.
Left to itself, Ray's driver would wait a minute for the GCS and then end with its own log line.
"""

from __future__ import annotations

import math
import re
import signal
import socket
import threading
import time
from collections import deque

from adademo_lerobot.collectors import CollectorConfig
from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.errors import (
    AdaDemoError,
    LostRayClusterError,
    MachineError,
    RoundAbortedError,
    machine_cause,
)
from adademo_lerobot.executors import RayArgs
from adademo_lerobot.executors.worker import EpisodeWorker
from adademo_lerobot.suites import TaskSuite

# Results are waited for in slices of this length; the cluster's health is checked at most this often, and no
# check waits longer than this (a GCS client call would otherwise retry for a minute when the GCS is gone).
WAIT_SLICE_S = 1.0
# A failed check is a lost cluster once checks have kept failing this long (not a blip of a busy machine).
CONFIRM_S = 2.0
# Most expert episodes one Ray call carries. Each call costs the driver ~1.4 ms of CPU (submitting it, fetching its
# result: benchmarks/results/driver_cost.md), an episode ~0.1 s of a worker's: a few episodes per call divide
# the driver's share, while the calls stay short enough to keep every worker busy until the round's end.
MAX_UNITS_PER_CALL = 8


def call_sizes(units: int, workers: int) -> list[int]:
    """How many units each Ray call carries, for `units` asked for together: as few calls as keep each at most
    `MAX_UNITS_PER_CALL`, as many for every worker (one unit per call when there are fewer units than workers),
    their sizes as even as can be, so that no worker is left with a longer share (episodes of a task take about
    as long as each other: with seconds-long experts an uneven last call would keep the others waiting)."""
    if units <= 0:
        return []
    calls = min(units, workers * math.ceil(units / (workers * MAX_UNITS_PER_CALL)))
    size, longer = divmod(units, calls)
    return [size + 1] * longer + [size] * (calls - longer)


class ClusterWatch:
    """Reads results (`get`) while it checks, about once a second, that the cluster can still deliver them."""

    def __init__(self, args: RayArgs):
        import ray

        try:
            self.gcs_address = ray.get_runtime_context().gcs_address
            host, _, port = self.gcs_address.rpartition(":")
            self._gcs: tuple[str, int] | None = (host.strip("[]"), int(port))
        except Exception:  # no GCS address here (Ray Client): results are waited for without the checks
            self.gcs_address, self._gcs = "unknown", None
        self._workers = args.num_workers
        self._per_worker = {"CPU": args.num_cpus_per_worker, "GPU": args.num_gpus_per_worker}
        self._per_worker = {k: v for k, v in self._per_worker.items() if v > 0}
        self._lock = threading.Lock()
        self._next_check = 0.0
        self._failing_since: float | None = None
        self._read_nodes = True
        # The most actors the cluster had room for: less room than that (and than needed) means a lost node.
        self._most_room = self._room() or 0
        self.lost: str | None = None  # what was seen, once the cluster is taken for lost
        self.stopped = threading.Event()  # the round stopped: results still awaited are given up

    def error(self) -> LostRayClusterError:
        return LostRayClusterError(
            f"lost the Ray cluster ({self.lost}): every committed demonstration is in the dataset; "
            "run the same command to resume"
        )

    def get(self, refs):
        """`ray.get(refs)` that raises `LostRayClusterError` within seconds when the cluster is gone."""
        import ray

        waiting = list(refs) if isinstance(refs, list) else [refs]
        while True:
            self.check()
            if self.lost is not None:
                raise self.error()
            if self.stopped.is_set():
                raise RoundAbortedError
            if waiting:
                _, waiting = ray.wait(waiting, num_returns=len(waiting), timeout=WAIT_SLICE_S)
            if not waiting:
                return self._get(refs)

    def _get(self, refs):
        """`ray.get`, with bad input found on a worker raised as the same one-line error as locally."""
        import ray
        from ray import exceptions as rex

        try:
            return ray.get(refs)
        except rex.RayTaskError as err:
            cause = getattr(err, "cause", None)
            if isinstance(cause, AdaDemoError):
                raise cause from None
            if isinstance(cause, OSError):  # the worker's machine: a full disk, a folder it cannot write
                what, first = machine_cause(cause)
                # Which call, on which node: only the error's text says (`ray::EpisodeWorker.collect_many() (pid=..,
                # ip=..)`; the error Ray raises here keeps neither as attributes).
                call = re.search(r"ray::\w+\.(\w+)\(", str(err))
                node = re.search(r"\bip=([\w.:-]+)", str(err))
                what_call = call.group(1).removesuffix("_many") if call else "task"  # collect_many: a collect
                raise MachineError(
                    f"a Ray worker's {what_call} failed on "
                    f"{node.group(1) if node else 'its node'} ({what}); the dataset is as its last commit left it: "
                    f"{first}run the same command to resume"
                ) from None
            raise
        except (rex.RayActorError, rex.LocalRayletDiedError, rex.NodeDiedError, rex.ObjectLostError) as err:
            if isinstance(err, rex.RayActorError) and err.actor_init_failed:
                raise  # the worker's code failed, not the machine
            # With unlimited restarts and retries, Ray only gives up on a worker it cannot bring back.
            self.lost = self.lost or f"Ray gave up on a worker: {str(err).strip().splitlines()[0][:160]}"
            raise self.error() from None

    def check(self) -> None:
        """Look at the cluster if a check is due (one thread at a time; the others keep waiting)."""
        if time.monotonic() < self._next_check or not self._lock.acquire(blocking=False):
            return
        try:
            problem = self.problem()
            now = time.monotonic()
            self._next_check = now + WAIT_SLICE_S
            if problem is None:
                self._failing_since = None
            elif self._failing_since is None:
                self._failing_since = now
            elif now - self._failing_since >= CONFIRM_S and self.lost is None:
                self.lost = f"{problem}; seen for {now - self._failing_since:.0f} s"
        finally:
            self._lock.release()

    def problem(self) -> str | None:
        """What is wrong with the cluster now, or None; takes at most 2 * WAIT_SLICE_S."""
        refused = self.gcs_refuses()
        if refused is not None:
            return refused
        room = self._room()
        if room is not None:
            self._most_room = max(self._most_room, room)
            if room < self._workers and room < self._most_room:
                need = ", ".join(f"{v:g} {k}" for k, v in self._per_worker.items())
                return f"its alive nodes have room for {room} of the {self._workers} workers ({need} each)"
        return None

    def gcs_refuses(self) -> str | None:
        """Why the GCS does not accept a TCP connection, or None when it does (a connect is ~0.1 ms). The kernel
        accepts for a live GCS however busy the machine is, so this does not mistake load for a loss."""
        if self._gcs is None:
            return None
        try:
            socket.create_connection(self._gcs, timeout=WAIT_SLICE_S).close()
        except OSError as err:
            why = err.strerror or str(err) or type(err).__name__
            return f"its GCS at {self.gcs_address} does not accept connections: {why}"
        return None

    def _room(self) -> int | None:
        """How many actors the alive nodes can hold at once; None when the GCS does not say within the slice (a
        GCS that is gone fails the connection check; a slow one is not a lost one)."""
        if not self._read_nodes or self._gcs is None:
            return None
        import ray

        try:
            from ray.core.generated.gcs_pb2 import GcsNodeInfo

            client = ray._private.worker.global_worker.gcs_client
            nodes = client.get_all_node_info(
                timeout=WAIT_SLICE_S, state_filter=GcsNodeInfo.GcsNodeState.ALIVE
            ).values()
        except ray.exceptions.RpcError:
            return None
        except Exception:  # private API of another Ray version: the connection check alone
            self._read_nodes = False
            return None
        return sum(
            min(math.floor(n.resources_total.get(k, 0.0) / v + 1e-9) for k, v in self._per_worker.items())
            for n in nodes
        )


class RayPending:
    """A call's result, fetched from Ray once: every unit a call carried reads it from here."""

    def __init__(self, ref, watch: ClusterWatch):
        self.ref, self._watch = ref, watch
        self._lock = threading.Lock()
        self._value, self._fetched = None, False

    def result(self):
        with self._lock:
            if not self._fetched:
                self._value, self._fetched = self._watch.get(self.ref), True
        return self._value

    def ready(self) -> bool:
        import ray

        return self._fetched or bool(ray.wait([self.ref], timeout=0)[0])


class RayUnit:
    """One unit of a call that carried several (`RayExecutor.collect_many`)."""

    def __init__(self, call: RayPending, index: int):
        self.call, self.index = call, index

    def result(self):
        return self.call.result()[self.index]

    def ready(self) -> bool:
        return self.call.ready()


class RayExecutor:
    parallel_tasks = True

    def __init__(
        self, args: RayArgs, suite: TaskSuite, collector_config: CollectorConfig, batch_size: int, device: str
    ):
        import ray

        self.batch_size = batch_size
        self._started_ray = not ray.is_initialized()
        if self._started_ray:
            # ray.init makes SIGTERM exit at once (status 15, no message, no held training step): the caller's
            # handler comes back after it.
            sigterm = signal.getsignal(signal.SIGTERM)
            try:
                ray.init(
                    address=args.address,
                    include_dashboard=False,
                    logging_level="WARNING",
                    configure_logging=True,
                    log_to_driver=True,
                )
            except (ConnectionError, ValueError, RuntimeError) as err:
                where = args.address or "a local Ray"
                raise AdaDemoError(
                    f"cannot start or reach {where}: {' '.join(str(err).split())[:200]}"
                ) from None
            finally:
                if sigterm is not None and threading.current_thread() is threading.main_thread():
                    signal.signal(signal.SIGTERM, sigterm)
        self._watch = ClusterWatch(args)
        threads = max(1, int(args.num_cpus_per_worker))
        actor = ray.remote(EpisodeWorker).options(
            num_cpus=args.num_cpus_per_worker,
            num_gpus=args.num_gpus_per_worker,
            max_restarts=-1,
            max_task_retries=-1,
            runtime_env={"env_vars": {"OMP_NUM_THREADS": str(threads)}},
        )
        self.actors = [
            actor.remote(suite.config.to_dict(), collector_config, batch_size, device, threads)
            for _ in range(args.num_workers)
        ]
        # Per worker, its calls not known to be finished, oldest first, with how many units each carries; and
        # the sum of those units (its load).
        self._inflight: list[deque[tuple[object, int]]] = [deque() for _ in self.actors]
        self._load = [0] * len(self.actors)
        # Per worker and kind of unit (method): the last unit's task, and when it was submitted (a count).
        self._last_task: list[dict[str, tuple[str, int]]] = [{} for _ in self.actors]
        self._submitted = 0
        self._lock = threading.Lock()
        self._policy: str | None = None
        # The workers write what they collect (--ray.worker_writes): where, set per round (None: frames come back).
        self.writes_shards = args.worker_writes
        self.shard_folder: str | None = None

    def _worker_for(self, method: str, task: str | None) -> int:
        """A worker with the fewest units in flight; among those, the one whose last unit of this kind (`method`) was
        of `task`, else the one that has gone longest without such a unit. A worker keeps only its last task's
        evaluation envs built (and a few tasks' expert envs), and strategies evaluate the tasks in turn, a few
        episodes each: placed by load alone, every batch went to the first idle worker, which built new envs for
        it (an MT10 round on 10 workers: 278 env builds for 304 evaluation episodes). The results are the same
        wherever a unit runs."""
        self._drop_finished()
        least = min(self._load)
        idle = [i for i, load in enumerate(self._load) if load == least]
        last = [self._last_task[i].get(method, (None, -1)) for i in range(len(self.actors))]
        return next((i for i in idle if last[i][0] == task), min(idle, key=lambda i: last[i][1]))

    def _drop_finished(self) -> None:
        """Forget the calls that have finished. A worker runs its calls in the order they were submitted, so its
        finished calls are its oldest: one `ray.wait` over every worker's oldest call, again while some had
        finished, instead of one per worker over all of its calls (each costs the driver ~0.1 ms: with 64
        workers that was ~6 ms per call submitted). Were a worker's calls to finish out of order, it would only
        look busier than it is until its oldest one finishes."""
        import ray

        while True:
            oldest = [calls[0][0] for calls in self._inflight if calls]
            if not oldest:
                return
            done, _ = ray.wait(oldest, num_returns=len(oldest), timeout=0, fetch_local=False)
            if not done:
                return
            finished = set(done)
            for i, calls in enumerate(self._inflight):
                if calls and calls[0][0] in finished:
                    self._load[i] -= calls.popleft()[1]

    def _submit(self, method: str, task: str | None, *args, units: int = 1) -> RayPending:
        if self._watch.lost is not None:  # no new work for a cluster that is gone
            raise self._watch.error()
        with self._lock:  # the tasks' loops submit from their own threads
            i = self._worker_for(method, task)
            ref = getattr(self.actors[i], method).remote(*args)
            self._inflight[i].append((ref, units))
            self._load[i] += units
            if task is not None:
                self._last_task[i][method] = (task, self._submitted)
                self._submitted += 1
        return RayPending(ref, self._watch)

    def use_policy(self, path: str | None) -> None:
        """Every worker loads the round's policy now, in parallel (and again by itself after a restart)."""
        self._policy = str(path) if path else None
        self._watch.get([a.use_policy.remote(self._policy) for a in self.actors])

    def evaluate(
        self, task: str, seeds: list[int], takeover: TakeoverArgs | None = None, keep_successes: bool = False
    ) -> RayPending:
        shards = self.shard_folder if keep_successes else None  # a kept success's frames stay on the worker
        return self._submit(
            "evaluate", task, task, list(seeds), self._policy, takeover, keep_successes, shards
        )

    def collect(
        self,
        task: str,
        seed: int,
        start_state: list[float] | None = None,
        takeover: TakeoverArgs | None = None,
    ) -> RayUnit:
        return self.collect_many(task, [(seed, start_state)], takeover)[0]

    def collect_many(
        self, task: str, units: list[tuple[int, list[float] | None]], takeover: TakeoverArgs | None = None
    ) -> list[RayUnit]:
        """Demonstrations from these (seed, start state) units, a few units per Ray call (`call_sizes`), in order.
        A unit's result is the same whichever call carries it."""
        pending, begin = [], 0
        for size in call_sizes(len(units), len(self.actors)):
            carried, begin = units[begin : begin + size], begin + size
            call = self._submit("collect_many", task, task, carried, takeover, self.shard_folder, units=size)
            pending += [RayUnit(call, k) for k in range(size)]
        return pending

    def prepare_merge(self, plan) -> RayPending:
        """A worker writes a planned merge's files beside the shards (`dataset/shard_merge.py`)."""
        return self._submit("prepare_merge", None, plan)

    def worker_pids(self) -> list[int]:
        return self._watch.get([a.pid.remote() for a in self.actors])

    def stop_waiting(self) -> None:
        self._watch.stopped.set()

    def close(self) -> None:
        import ray

        if self._watch.gcs_refuses() is not None:
            # The GCS is gone: ray.kill and ray.shutdown would wait for it. A command that lost its cluster leaves
            # at once (LostRayClusterError); what a local Ray left running dies with this process (fate sharing).
            return
        for a in self.actors:
            ray.kill(a)
        if self._started_ray:
            ray.shutdown()
