"""`--executor=ray`: episodes run on Ray actors (this machine, or a cluster at `--ray.address`).

Each actor is an `EpisodeWorker`: it builds the suite's envs and the expert once and loads a round's policy once.
Units of work go to the actor with the fewest unfinished units. Ray restarts an actor whose process dies
(`kill -9`) and runs its unfinished units again (`max_restarts`, `max_task_retries`), so a round completes
with nothing lost or duplicated: units are deterministic, and the caller records each result once.
"""

from __future__ import annotations

import os
import threading

from adademo_lerobot.collectors import CollectorConfig
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.executors import RayArgs
from adademo_lerobot.executors.worker import EpisodeWorker
from adademo_lerobot.suites import TaskSuite
from adademo_lerobot.takeover import TakeoverArgs


def ray_get(refs):
    """`ray.get`, with bad input found on a worker raised as the same one-line error as locally."""
    import ray

    try:
        return ray.get(refs)
    except ray.exceptions.RayTaskError as err:
        cause = getattr(err, "cause", None)
        if isinstance(cause, AdaDemoError):
            raise cause from None
        raise


class RayPending:
    def __init__(self, ref):
        self.ref = ref

    def result(self):
        return ray_get(self.ref)


class RayExecutor:
    parallel_tasks = True

    def __init__(
        self, args: RayArgs, suite: TaskSuite, collector_config: CollectorConfig, batch_size: int, device: str
    ):
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no network beyond the package registries
        import ray

        self.batch_size = batch_size
        self._started_ray = not ray.is_initialized()
        if self._started_ray:
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
        self._inflight: list[list] = [[] for _ in self.actors]
        self._lock = threading.Lock()
        self._policy: str | None = None

    def _least_loaded(self) -> int:
        import ray

        for refs in self._inflight:
            if refs:
                done, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
                finished = set(done)
                refs[:] = [r for r in refs if r not in finished]
        return min(range(len(self.actors)), key=lambda i: len(self._inflight[i]))

    def _submit(self, method: str, *args) -> RayPending:
        with self._lock:  # the tasks' loops submit from their own threads
            i = self._least_loaded()
            ref = getattr(self.actors[i], method).remote(*args)
            self._inflight[i].append(ref)
        return RayPending(ref)

    def use_policy(self, path: str | None) -> None:
        """Every worker loads the round's policy now, in parallel (and again by itself after a restart)."""
        self._policy = str(path) if path else None
        ray_get([a.use_policy.remote(self._policy) for a in self.actors])

    def evaluate(self, task: str, seeds: list[int], takeover: TakeoverArgs | None = None) -> RayPending:
        return self._submit("evaluate", task, list(seeds), self._policy, takeover)

    def collect(
        self,
        task: str,
        seed: int,
        start_state: list[float] | None = None,
        takeover: TakeoverArgs | None = None,
    ) -> RayPending:
        return self._submit("collect", task, seed, start_state, takeover)

    def worker_pids(self) -> list[int]:
        import ray

        return ray.get([a.pid.remote() for a in self.actors])

    def close(self) -> None:
        import ray

        for a in self.actors:
            ray.kill(a)
        if self._started_ray:
            ray.shutdown()
