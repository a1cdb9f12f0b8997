"""Where episodes run: `--executor=local` (default: in this process, no Ray needed) or `--executor=ray` (Ray
actors on this machine or a cluster: `--ray.address`, `--ray.num_workers`, `--ray.num_cpus_per_worker`,
`--ray.num_gpus_per_worker`).

Both hand out the same units of work (a batch of seeds to evaluate, one seed to collect a demonstration from) and
return results as `Pending` values that the caller reads in its own order. The local executor computes a unit
only when its result is read, so asking ahead costs nothing and a round runs exactly as a sequential loop would;
the Ray executor starts every unit at once on its workers. Units are deterministic (every random draw comes from
the unit's seeds), so both give the same results whatever the number of workers or the order of completion.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from adademo_lerobot.collectors import CollectorConfig
from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.episodes import CollectionResult, EpisodeRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.executors.worker import EpisodeWorker
from adademo_lerobot.suites import TaskSuite

if TYPE_CHECKING:
    from adademo_lerobot.dataset.shard_merge import MergePlan

EXECUTORS = ("local", "ray")


@dataclass
class RayArgs:
    # Address of a running Ray cluster (`ray start --head` prints it); default: start a local Ray for the command.
    address: str | None = None
    # Ray actors, each with its own envs, expert and copy of the policy.
    num_workers: int = 2
    num_cpus_per_worker: float = 1.0
    num_gpus_per_worker: float = 0.0
    # Workers write the demonstrations they collect beside the dataset (`.<dataset>.adademo-shards/`, on storage
    # every node reaches) and commits merge them: frames never travel through the driver. false: frames come
    # back to the driver, which writes them (a cluster without shared storage).
    worker_writes: bool = True


@dataclass
class ThreadArgs:
    """The flag of every command that computes with torch (training among them)."""

    # torch intra-op threads of this process (2-core default; lower it when env worker processes run beside it).
    torch_threads: int = 2

    def validate_threads(self) -> None:
        if self.torch_threads < 1:
            raise AdaDemoError(f"--torch_threads must be >= 1, got {self.torch_threads}")


@dataclass
class ComputeArgs(ThreadArgs):
    """The flags of every command that runs a policy in this process (a robot's round among them)."""

    # Device of the policy (cpu, cuda, mps).
    device: str = "cpu"

    def validate_device(self) -> None:
        """A device torch has here (the policy runs in this process; Ray workers check their own)."""
        check_torch_device(self.device)


@dataclass
class ExecutionArgs(ComputeArgs):
    """Where a command's episodes run and with what: the flags every command that runs simulated episodes
    shares."""

    # Where episodes run: `local` (this process) or `ray` (Ray actors; see --ray.*).
    executor: str = "local"
    ray: RayArgs = field(default_factory=RayArgs)

    def validate_execution(self) -> None:
        self.validate_threads()
        check_executor_args(self.executor, self.ray)
        if self.executor == "local":
            self.validate_device()


class Pending(Protocol):
    def result(self) -> Any: ...
    def ready(self) -> bool: ...  # whether `result()` would return without waiting for a worker


class Lazy:
    """A result computed when first read (the local executor's way of being asked ahead)."""

    def __init__(self, compute: Callable[[], Any]):
        self._compute, self._done, self._value = compute, False, None

    def result(self) -> Any:
        if not self._done:
            self._value, self._done, self._compute = self._compute(), True, None
        return self._value

    def ready(self) -> bool:
        return True  # computed here, when read


class Executor(Protocol):
    batch_size: int
    parallel_tasks: bool  # True: the caller may run several tasks' loops at once (their units interleave)
    # True: collected demonstrations are written by the workers into `shard_folder` (when the caller sets one)
    # and come back as shards (`dataset/shards.py`), not frames.
    writes_shards: bool
    shard_folder: str | None

    def use_policy(self, path: str | None) -> None: ...
    def evaluate(
        self, task: str, seeds: list[int], takeover: TakeoverArgs | None = None, keep_successes: bool = False
    ) -> Pending: ...
    def collect(
        self,
        task: str,
        seed: int,
        start_state: list[float] | None = None,
        takeover: TakeoverArgs | None = None,
    ) -> Pending: ...
    # `collect` for each (seed, start state) unit: the Ray executor sends a few units per call.
    def collect_many(
        self, task: str, units: list[tuple[int, list[float] | None]], takeover: TakeoverArgs | None = None
    ) -> list[Pending]: ...
    # Writes a planned merge's files (`dataset/shard_merge.py`) where the executor's workers are.
    def prepare_merge(self, plan: MergePlan) -> Pending: ...
    # The round stops: results still awaited raise RoundAbortedError instead (their units are given up; the
    # executor is then only closed).
    def stop_waiting(self) -> None: ...
    def close(self) -> None: ...


class LocalExecutor:
    """One worker in this process; units run when their result is read."""

    parallel_tasks = False
    writes_shards = False  # frames are already where the dataset is written
    shard_folder = None

    def __init__(
        self,
        suite: TaskSuite,
        collector_config: CollectorConfig,
        batch_size: int,
        device: str,
        torch_threads: int,
    ):
        self.batch_size = batch_size
        self.worker = EpisodeWorker(
            suite.config.to_dict(), collector_config, batch_size, device, torch_threads
        )
        self.worker.suite = suite  # the caller's suite object (its envs and state samplers are reused)
        self._policy: str | None = None

    def use_policy(self, path: str | None) -> None:
        self._policy = str(path) if path else None
        self.worker.use_policy(self._policy)

    def evaluate(
        self, task: str, seeds: list[int], takeover: TakeoverArgs | None = None, keep_successes: bool = False
    ) -> Lazy:
        policy = self._policy
        return Lazy(lambda: self.worker.evaluate(task, list(seeds), policy, takeover, keep_successes))

    def collect(
        self,
        task: str,
        seed: int,
        start_state: list[float] | None = None,
        takeover: TakeoverArgs | None = None,
    ) -> Lazy:
        return Lazy(lambda: self.worker.collect(task, seed, start_state, takeover))

    def collect_many(
        self, task: str, units: list[tuple[int, list[float] | None]], takeover: TakeoverArgs | None = None
    ) -> list[Lazy]:
        return [self.collect(task, seed, start, takeover) for seed, start in units]

    def prepare_merge(self, plan: MergePlan) -> Lazy:
        return Lazy(lambda: self.worker.prepare_merge(plan))

    def stop_waiting(self) -> None:
        pass  # units run in the caller's thread, which the round stops itself

    def close(self) -> None:
        self.worker.close()


def check_torch_device(device: str) -> None:
    """`--device` names a device torch can use on this machine."""
    if device == "cpu":
        return  # without importing torch: flags are checked before the heavy imports
    import torch

    try:
        parsed = torch.device(device)
    except RuntimeError:
        raise AdaDemoError(
            f"--device={device!r} is not a torch device; use cpu, cuda, cuda:N or mps"
        ) from None
    kind = parsed.type
    available = {
        "cpu": True,
        "cuda": torch.cuda.is_available(),
        "mps": torch.backends.mps.is_available(),
    }
    if kind not in available:
        raise AdaDemoError(f"--device={device!r}: adademo runs policies on cpu, cuda or mps")
    if not available[kind]:
        raise AdaDemoError(
            f"--device={device}: torch finds no {kind} device on this machine; use --device=cpu"
        )
    if kind == "cuda" and parsed.index is not None and parsed.index >= torch.cuda.device_count():
        raise AdaDemoError(f"--device={device}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def unreachable_head(address: str | None, timeout: float = 5.0) -> str | None:
    """Why nothing accepts connections at a `HOST:PORT` (or `ray://HOST:PORT`) head address, or None (it does, or
    the address is `auto`, `local` or none: Ray finds or starts a cluster itself)."""
    if not address or address in ("auto", "local"):
        return None
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return f"{address!r} is not HOST:PORT"
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            return None
    except OSError as err:
        return err.strerror or type(err).__name__


def check_executor_args(executor: str, ray: RayArgs) -> None:
    if executor not in EXECUTORS:
        raise AdaDemoError(f"unknown --executor={executor!r}; choose one of {', '.join(EXECUTORS)}")
    if executor == "ray":
        if ray.num_workers < 1:
            raise AdaDemoError(f"--ray.num_workers must be >= 1, got {ray.num_workers}")
        if ray.num_cpus_per_worker <= 0 or ray.num_gpus_per_worker < 0:
            raise AdaDemoError("--ray.num_cpus_per_worker must be > 0 and --ray.num_gpus_per_worker >= 0")
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise AdaDemoError(
                "--executor=ray needs Ray, which is not installed: pip install 'adademo-lerobot[ray]'"
            )
        if why := unreachable_head(ray.address):
            # ray.init would wait a minute or more for a head that is not there, printing only its own lines.
            raise AdaDemoError(
                f"cannot reach the Ray cluster at --ray.address={ray.address}: {why}; start it (ray start --head) "
                "or fix the address"
            )


def make_executor(
    execution: ExecutionArgs, suite: TaskSuite, collector_config: CollectorConfig, batch_size: int
) -> Executor:
    execution.validate_execution()
    if batch_size < 1:
        raise AdaDemoError(f"--eval.batch_size must be >= 1, got {batch_size}")
    if execution.executor == "local":
        return LocalExecutor(suite, collector_config, batch_size, execution.device, execution.torch_threads)
    from adademo_lerobot.executors.ray_executor import RayExecutor

    return RayExecutor(execution.ray, suite, collector_config, batch_size, execution.device)


__all__ = [
    "EXECUTORS",
    "CollectionResult",
    "ComputeArgs",
    "ExecutionArgs",
    "EpisodeRecord",
    "Executor",
    "Lazy",
    "LocalExecutor",
    "Pending",
    "RayArgs",
    "ThreadArgs",
    "check_executor_args",
    "make_executor",
]
