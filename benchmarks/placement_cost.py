"""What placing a unit on a Ray worker costs the driver, by number of workers and units in flight.

    python benchmarks/placement_cost.py

`RayExecutor._worker_for` (the executor's own method) picks the worker for every unit a round submits. It first
forgets the units that have finished; how it finds them is what this measures, against the way it did before
(one `ray.wait` per worker over all of that worker's units, written out below). The workers are slots of a
`RayExecutor` whose units in flight are real Ray object refs of one actor kept busy, so none finishes while it is
timed (what a round with units queued on every worker looks like); no EpisodeWorker is started, so 64 workers fit
on a small machine. Writes benchmarks/results/placement_cost.md.
"""

from __future__ import annotations

import os
import time
from collections import deque

from _common import RESULTS, machine_line

SUBMITS = 300  # placements timed per row and method


def previous_worker_for(executor, method: str, task: str | None) -> int:
    """The placement before 2026-12-05: one `ray.wait` per worker over all of its units."""
    import ray

    for refs in executor._inflight:
        if refs:
            done, _ = ray.wait(list(refs), num_returns=len(refs), timeout=0)
            finished = set(done)
            kept = [r for r in refs if r not in finished]
            refs.clear()
            refs.extend(kept)
    least = min(len(refs) for refs in executor._inflight)
    idle = [i for i, refs in enumerate(executor._inflight) if len(refs) == least]
    last = [executor._last_task[i].get(method, (None, -1)) for i in range(len(executor.actors))]
    return next((i for i in idle if last[i][0] == task), min(idle, key=lambda i: last[i][1]))


def main() -> None:
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    from adademo_lerobot.executors.ray_executor import RayExecutor

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, logging_level="ERROR")

    @ray.remote
    class Busy:
        def wait(self, seconds: float) -> None:
            time.sleep(seconds)

        def unit(self, *args) -> int:
            return 0

    busy = Busy.remote()
    busy.wait.remote(600)  # every unit below queues behind this one: none finishes while timed

    def slots(workers: int, in_flight: int) -> RayExecutor:
        executor = RayExecutor.__new__(RayExecutor)  # its placement state only: no Ray workers started
        executor.actors = [None] * workers
        executor._inflight = [deque(busy.unit.remote() for _ in range(in_flight)) for _ in range(workers)]
        executor._last_task = [{} for _ in range(workers)]
        executor._submitted = 0
        return executor

    rows = []
    for workers, in_flight in ((2, 10), (8, 10), (64, 2), (64, 16), (64, 80)):
        executor = slots(workers, in_flight)
        ms = {"now": [], "before": []}
        for _ in range(3):  # alternating, so that a drift of the machine's speed touches both alike
            for name, place in (
                ("now", executor._worker_for),
                ("before", lambda m, t, ex=executor: previous_worker_for(ex, m, t)),
            ):
                start = time.perf_counter()
                for k in range(SUBMITS):
                    place("collect", f"task-{k % 10}")
                ms[name].append((time.perf_counter() - start) / SUBMITS * 1e3)
        now, before = sorted(ms["now"])[1], sorted(ms["before"])[1]
        rows.append((workers, in_flight, now, before))
        print(f"{workers} workers x {in_flight} in flight: {now:.3f} ms now, {before:.3f} ms before")
    # Ray's own submission of a unit with a collection's arguments (task, seed, no start state, no takeover, the
    # shard folder), which every unit costs the driver besides its placement.
    start = time.perf_counter()
    for k in range(2000):
        busy.unit.remote("push-v3", k, None, None, "/tmp/shards/round-001")
    submit_ms = (time.perf_counter() - start) / 2000 * 1e3
    print(f"ray submit: {submit_ms:.3f} ms per unit")
    ray.shutdown()

    lines = [
        "# Placing a unit on a Ray worker: the driver's time per unit submitted",
        "",
        f"Command: `python benchmarks/placement_cost.py`; {machine_line()}.",
        "`RayExecutor._worker_for` on executors of W worker slots with N units in flight on each (real Ray refs of "
        "one busy actor, so none finishes while timed), 300 placements per figure, the median of three alternating "
        "runs per method. Now: one `ray.wait` over every worker's oldest unit (a worker runs its units in order). "
        "Before: one `ray.wait` per worker over all of its units.",
        "",
        "| workers | units in flight per worker | now: ms per unit | before: ms per unit | before / now |",
        "| --- | --- | --- | --- | --- |",
        *(f"| {w} | {n} | {now:.3f} | {before:.3f} | {before / now:.1f} |" for w, n, now, before in rows),
        "",
        f"Ray's own submission of a unit (`actor.method.remote(...)` with a collection's arguments, 2000 of them): "
        f"{submit_ms:.3f} ms per unit, at any number of workers.",
        "",
        "A round's driver budget is ~1 ms per demonstration for 64 workers (issue 39): placement alone took more "
        "than that before at 64 workers, as each `ray.wait` call costs the driver ~0.1 ms whatever it waits for.",
    ]
    (RESULTS / "placement_cost.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS / 'placement_cost.md'}")


if __name__ == "__main__":
    main()
