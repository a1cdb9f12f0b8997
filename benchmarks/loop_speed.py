"""How fast the loop runs episodes, against the simulator itself, and what Ray costs.

    python benchmarks/loop_speed.py [--episodes 40] [--demos 20]

One run, one machine:
1. Local executor (this process, one core for inference): fixed-set evaluation of a small ACT (the
   `policies/act_state_cpu.yaml` preset, briefly trained, so most episodes run to the step limit) and scripted
   expert collection, on 4 MetaWorld tasks. "Raw" is the bare MetaWorld `env.step` of the very same episodes:
   the time spent inside it is measured during the loop, so loop / raw is the share of the loop's time the
   simulator gets (everything else: restores, our env wrapper, policy inference, recording, bookkeeping).
2. Ray executor with 1 and 2 workers on the same episodes (same results: the executor tests check it),
   throughput as a ratio to (workers x the raw rate of step 1); Ray's fixed cost per command (start a local
   Ray, create the actors, load the policy) and its cost per episode against local.
3. What the driver does per collected demonstration (journal fsync, result transfer, writing it: appending the
   frames, or merging the shard a worker wrote), measured, and the ceiling that puts on a round however many
   workers run episodes.
Writes benchmarks/results/loop_speed.md.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from _common import RESULTS, StepClock, collect, loop_speed_args, machine_line, train_small_act

from adademo_lerobot.strategies.round_commits import MERGE_EVERY

TASKS = ["reach-v3", "push-v3", "drawer-open-v3", "pick-place-v3"]


def run_units(executor, suite, ckpt: str, episodes: int, demos: int, seed: int) -> dict:
    from adademo_lerobot.loop.evaluate import evaluate_fixed_set

    executor.use_policy(ckpt)
    start = time.perf_counter()
    records, eval_steps, _ = evaluate_fixed_set(suite, executor, seed, episodes)
    eval_seconds = time.perf_counter() - start
    start = time.perf_counter()
    # As a round asks for a task's demonstrations: all at once (a Ray executor sends a few per call).
    pending = [p for task in TASKS for p in executor.collect_many(task, draws(seed * 1000, demos))]
    results = [p.result() for p in pending]
    collect_seconds = time.perf_counter() - start
    return {
        "eval_steps": eval_steps,
        "eval_seconds": eval_seconds,
        "collect_steps": sum(r.env_steps for r in results),
        "collect_seconds": collect_seconds,
        "outcomes": [(r.seed, r.success, r.steps) for r in records],
        "demos": [(r.seed, r.env_steps) for r in results],
    }


class CallClock:
    """Times the calls of the callables it wraps (measurement only): the expert's action function, the policy's
    preprocessing, inference and postprocessing."""

    def __init__(self):
        self.seconds = 0.0

    def wrap(self, fn):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start

        return timed

    def reset(self) -> None:
        self.seconds = 0.0


def where_time_goes(suite, ckpt: str, clock: StepClock, episodes: int, demos: int) -> dict:
    """A local run of its own: the seconds of the whole loop, of the simulator's step, and of the work any loop must
    do beside it (the expert's action function; the policy's preprocessing, chunk inference and postprocessing)."""
    from adademo_lerobot.collectors import ScriptedCollectorConfig
    from adademo_lerobot.collectors.metaworld_scripted import MetaWorldScriptedExpert
    from adademo_lerobot.core.patching import temporarily_set
    from adademo_lerobot.executors import LocalExecutor
    from adademo_lerobot.loop.evaluate import evaluate_fixed_set

    expert, policy = CallClock(), CallClock()
    stock = MetaWorldScriptedExpert.expert_for
    timed_expert = lambda self, task: expert.wrap(stock(self, task))  # noqa: E731
    local = LocalExecutor(suite, ScriptedCollectorConfig(), batch_size=10, device="cpu", torch_threads=1)
    with temporarily_set(MetaWorldScriptedExpert, "expert_for", timed_expert):
        run_units(local, suite, ckpt, 2, 1, seed=99)  # warm-up
        loaded = local.worker._evaluator.loaded
        loaded.preprocessor = policy.wrap(loaded.preprocessor)
        loaded.postprocessor = policy.wrap(loaded.postprocessor)
        loaded.policy.predict_action_chunk = policy.wrap(loaded.policy.predict_action_chunk)
        clock.reset()
        start = time.perf_counter()
        evaluate_fixed_set(suite, local, 2, episodes)
        split = {"eval": (time.perf_counter() - start, clock.seconds, policy.seconds)}
        clock.reset()
        start = time.perf_counter()
        for p in [p for task in TASKS for p in local.collect_many(task, draws(2000, demos))]:
            p.result()
        split["collect"] = (time.perf_counter() - start, clock.seconds, expert.seconds)
    local.close()
    return split


def draws(first: int, n: int) -> list[tuple[int, None]]:
    return [(first + k, None) for k in range(n)]


def fetched(executor, task: str, seeds: range) -> tuple[list, float, float]:
    """Collect at `seeds`: the results, the seconds per result of fetching them once every one is ready on the
    workers (the transfer alone, not the wait), and the workers' demonstrations per second (submit to all ready).
    Ten results are fetched first and not counted: unpickling the first one imports the modules its classes
    live in (pandas and pyarrow among them), ~0.4 s once per process, which showed as 2-4 ms a result over the first
    160 (2026-12-04; 0.24-0.44 ms after)."""
    import ray

    for p in executor.collect_many(task, draws(seeds.start - 10, 10)):
        p.result()
    start = time.perf_counter()
    pending = executor.collect_many(task, draws(seeds.start, len(seeds)))
    calls = list({p.call.ref: None for p in pending})
    ray.wait(calls, num_returns=len(calls))
    rate = len(pending) / (time.perf_counter() - start)
    start = time.perf_counter()
    results = [p.result() for p in pending]
    return results, (time.perf_counter() - start) / len(pending), rate


def driver_costs(suite, executor, tmp: Path, demos: int) -> dict:
    """Per-episode driver work: a journal line (synced before each commit); a collected demonstration fetched from a worker and
    written, either as frames appended by the driver or as a shard the worker wrote and the driver merges (both
    committed 10 at a time, as `--commit_every` does by default)."""
    from adademo_lerobot.dataset.info import read_info
    from adademo_lerobot.dataset.ledger import RoundJournal
    from adademo_lerobot.dataset.shard_merge import ShardMerger
    from adademo_lerobot.dataset.store import DemoDataset
    from adademo_lerobot.strategies.round_commits import OrderedAppender

    journal = RoundJournal(tmp / "journal", 1)
    start = time.perf_counter()
    for k in range(200):  # as a round journals: a line per answer, made durable before each commit of 10
        journal.append(
            {"type": "demo", "task": "reach-v3", "seed": k, "steps": 200, "frames": 80}, sync=False
        )
        if k % 10 == 9:
            journal.sync()
    journal_s = (time.perf_counter() - start) / 200
    executor.shard_folder = None  # frames come back
    results, fetch_s, frames_rate = fetched(executor, "push-v3", range(7000, 7000 + demos))
    good = [r.demonstration for r in results if r.demonstration is not None]
    appended, merged = DemoDataset("local/bench", tmp / "appends", suite.config), tmp / "merges"
    appended.append(suite, good[:1], 0, "bench", "metaworld-scripted")  # create it
    DemoDataset("local/bench", merged, suite.config).append(suite, good[:1], 0, "bench", "metaworld-scripted")
    start = time.perf_counter()
    for begin in range(1, len(good), 10):
        appended.append(suite, good[begin : begin + 10], 1, "bench", "metaworld-scripted")
    append_s = (time.perf_counter() - start) / max(len(good) - 1, 1)
    executor.shard_folder = str(tmp / "shards")  # the workers write what they collect
    results, fetch_shard_s, shards_rate = fetched(executor, "push-v3", range(7000, 7000 + demos))
    shards = [r.demonstration for r in results if r.demonstration is not None][1:]
    merger = ShardMerger(DemoDataset.open("local/bench", merged))  # as a round's appender holds one
    start = time.perf_counter()
    for begin in range(0, len(shards), 10):
        merger.merge(shards[begin : begin + 10], 1, "bench", "metaworld-scripted")
    merge_s = (time.perf_counter() - start) / max(len(shards), 1)
    # As a round commits them: a journal line per commit of 10, merged MERGE_EVERY at a time and at the end.
    deferred = tmp / "deferred"
    DemoDataset("local/bench", deferred, suite.config).append(
        suite, good[:1], 0, "bench", "metaworld-scripted"
    )
    dataset = DemoDataset.open("local/bench", deferred)
    appender = OrderedAppender(
        dataset,
        suite,
        1,
        "bench",
        "metaworld-scripted",
        10,
        None,
        RoundJournal(deferred, 1),
        executor.prepare_merge,
    )
    # The driver's CPU time (every thread of this process, Ray's own included), and the wall time to the last
    # merge's commit (which waits for a worker to write its files).
    cpu, start = time.process_time(), time.perf_counter()
    for shard in shards:
        appender.add(shard.task, shard)
    appender.close()
    round_s = (time.process_time() - cpu) / max(len(shards), 1)
    round_wall_s = (time.perf_counter() - start) / max(len(shards), 1)
    assert read_info(deferred)["total_episodes"] == len(shards) + 1
    executor.shard_folder = None
    return {
        "round_s": round_s,
        "round_wall_s": round_wall_s,
        "shards": len(shards),
        "journal_s": journal_s,
        "fetch_s": fetch_s,
        "append_s": append_s,
        "fetch_shard_s": fetch_shard_s,
        "merge_s": merge_s,
        "frames_rate": frames_rate,
        "shards_rate": shards_rate,
    }


def two_nodes(suite, ckpt: str, args, base: dict, shards: Path) -> dict:
    """The same units on a two-node Ray cluster on this machine (`ray.cluster_utils.Cluster`, one CPU per node, so
    one worker on each): results and shards cross a node boundary."""
    from ray.cluster_utils import Cluster

    from adademo_lerobot.executors import RayArgs

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        ray_args = RayArgs(address=cluster.address, num_workers=2)
        ray, _, result = on_ray(suite, ckpt, args, base, ray_args, shards)
        close_ray(ray)
    finally:
        cluster.shutdown()
    return result


def step_clock_hook(folder: str):
    """A Ray worker-process setup hook (measurement only): the worker's bare MetaWorld step timed as `StepClock` times
    it locally, its totals (steps, seconds) written to `folder`/<pid>.json every 100 steps. Self-contained: Ray
    ships it to the workers by value."""

    def install():
        import json
        import os
        import time

        from adademo_lerobot.suites.metaworld import MetaWorldTaskEnv

        stock, totals, path = (
            MetaWorldTaskEnv._raw_step,
            [0, 0.0],
            os.path.join(folder, f"{os.getpid()}.json"),
        )

        def timed(env, action):
            start = time.perf_counter()
            out = stock(env, action)
            totals[1] += time.perf_counter() - start
            totals[0] += 1
            if totals[0] % 100 == 0:
                with open(path, "w") as f:
                    json.dump(totals, f)
            return out

        MetaWorldTaskEnv._raw_step = timed

    return install


def workers_raw_rate(folder: Path) -> float:
    """The workers' raw rates (steps/s of their bare step), summed: the ideal for that many workers."""
    import json

    return sum(
        steps / seconds for steps, seconds in (json.loads(f.read_text()) for f in folder.glob("*.json"))
    )


def close_ray(executor) -> None:
    """Close an executor `on_ray` made, and the Ray it started (with the workers' clocks)."""
    import ray

    executor.close()
    ray.shutdown()


def rates(r: dict) -> tuple[float, float, float | None]:
    """Evaluation, collection and (where measured) shard-writing collection steps/s of a run's units."""
    shards = r["collect_steps"] / r["shard_seconds"] if "shard_seconds" in r else None
    return r["eval_steps"] / r["eval_seconds"], r["collect_steps"] / r["collect_seconds"], shards


def on_ray(suite, ckpt: str, args, base: dict, ray_args, shards: Path) -> tuple:
    """A Ray executor with the policy loaded (left open: `close_ray`), its fixed cost in seconds (start Ray or connect, create
    the actors, load the policy), and the units' results, checked equal to the local ones; then the same
    collection as a round runs it by default, each worker writing what it collects as a shard under `shards`."""
    import ray as ray_module

    from adademo_lerobot.collectors import ScriptedCollectorConfig
    from adademo_lerobot.executors import ExecutionArgs, make_executor

    clocks = shards.with_name(shards.name + "-clocks")
    clocks.mkdir()
    start = time.perf_counter()
    ray_module.init(
        address=ray_args.address,
        include_dashboard=False,
        logging_level="WARNING",
        runtime_env={"worker_process_setup_hook": step_clock_hook(str(clocks))},
    )
    execution = ExecutionArgs(torch_threads=1, executor="ray", ray=ray_args)
    ray = make_executor(execution, suite, ScriptedCollectorConfig(), 10)
    ray.use_policy(ckpt)
    fixed = time.perf_counter() - start
    # The same warm-up as the local executor's (each worker's first inference, its first envs and expert), so that
    # both are timed in their steady state.
    for _ in ray.actors:
        run_units(ray, suite, ckpt, 2, 1, seed=99)
    result = run_units(ray, suite, ckpt, args.episodes, args.demos, seed=1)
    assert result["outcomes"] == base["outcomes"] and result["demos"] == base["demos"], "results differ"
    # A worker's first shard also imports the writer (pyarrow's and `datasets`' modules, ~0.3 s once per worker
    # and command): written in a warm-up, as the other first calls are, and timed.
    ray.shard_folder = str(shards.with_name(shards.name + "-warm-up"))
    start = time.perf_counter()
    for _ in ray.actors:
        [p.result() for t in TASKS for p in ray.collect_many(t, draws(98_000, 1))]
    result["shard_warm_up_seconds"] = time.perf_counter() - start
    ray.shard_folder = str(shards)
    start = time.perf_counter()
    written = [p.result() for p in [p for t in TASKS for p in ray.collect_many(t, draws(1000, args.demos))]]
    result["shard_seconds"] = time.perf_counter() - start
    assert [(r.seed, r.env_steps) for r in written] == base["demos"], "results differ"
    ray.shard_folder = None
    result["raw_rate"] = workers_raw_rate(clocks)
    return ray, fixed, result


def main() -> None:
    args = loop_speed_args(40, "fixed-set episodes per task", "expert episodes per task")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # as the commands do: no network
    from adademo_lerobot.collectors import ScriptedCollectorConfig
    from adademo_lerobot.executors import LocalExecutor, RayArgs
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS), max_episode_steps=200))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ckpt = str(train_small_act(collect(tmp / "ds", ",".join(TASKS), 3), tmp / "train", steps=20))
        from adademo_lerobot.suites.metaworld import MetaWorldTaskEnv

        clock = StepClock(MetaWorldTaskEnv)  # the bare MetaWorld step
        split = where_time_goes(suite, ckpt, clock, args.episodes, args.demos)
        local = LocalExecutor(suite, ScriptedCollectorConfig(), batch_size=10, device="cpu", torch_threads=1)
        run_units(local, suite, ckpt, 2, 1, seed=99)  # warm-up: first inference and env construction
        clock.reset()
        base = run_units(local, suite, ckpt, args.episodes, args.demos, seed=1)
        raw_rate = base["raw_rate"] = clock.steps / clock.seconds
        local.close()
        rows = [("local", 1, base)]
        fixed = {}
        for workers in (1, 2):
            ray_args = RayArgs(num_workers=workers)
            ray, fixed[workers], result = on_ray(suite, ckpt, args, base, ray_args, tmp / f"shards-{workers}")
            rows.append(("ray", workers, result))
            if workers == 2:
                driver = driver_costs(suite, ray, tmp, 4 * args.demos)
            close_ray(ray)
        rows.append(("ray, 2 nodes", 2, two_nodes(suite, ckpt, args, base, tmp / "shards-nodes")))

    episodes = len(base["outcomes"])
    lines = [
        "# Loop speed: evaluation and collection against the simulator, local and Ray",
        "",
        f"Command: `python benchmarks/loop_speed.py --episodes {args.episodes} --demos {args.demos}`; {machine_line()}.",
        f"Tasks {', '.join(TASKS)} (state observations, 200-step limit). Evaluation: {args.episodes} fixed-set episodes "
        "per task, batches of 10, a small ACT (`policies/act_state_cpu.yaml`, 20 training steps: most episodes run "
        f"to the limit). Collection: {args.demos} scripted-expert episodes per task (recorded and sent back, not "
        "written; in the last two columns each Ray worker writes what it collects as a shard and sends back its "
        "description, as a round does by default). "
        "Raw = the bare MetaWorld `env.step` of the same episodes, timed inside each process that steps: the local "
        f"run's (**{raw_rate:.0f} steps/s** on this machine), each Ray worker's (a worker setup hook; the workers' "
        "rates summed: the ideal for that many workers). Ray results were checked equal to local ones (same outcomes "
        "and steps per episode, same demonstrations).",
        "",
        "| executor | workers | raw steps/s | eval steps/s | eval / raw | collection steps/s | collection / raw | "
        "collection writing shards (a round's default) steps/s | / raw |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, workers, r in rows:
        ev, co, sh = rates(r)
        raw = r["raw_rate"]
        written = f"{sh:.0f} | {sh / raw:.2f}" if sh else "(appends in-process) | -"
        lines.append(
            f"| {name} | {workers} | {raw:.0f} | {ev:.0f} | {ev / raw:.2f} | {co:.0f} | {co / raw:.2f} | {written} |"
        )
    per_episode = (rows[1][2]["eval_seconds"] - base["eval_seconds"]) / episodes
    per_demo = (rows[1][2]["collect_seconds"] - base["collect_seconds"]) / (len(TASKS) * args.demos)
    per_demo_append_s = driver["journal_s"] + driver["fetch_s"] + driver["append_s"]
    per_demo_merge_s = driver["journal_s"] + driver["fetch_shard_s"] + driver["merge_s"]
    per_demo_round_s = driver["journal_s"] + driver["fetch_shard_s"] + driver["round_s"]
    ev_local, co_local, _ = rates(base)
    ray1 = rows[1][2]
    ray1_eval, ray1_collect, ray1_shards = rates(ray1)
    demos_per_s = ray1_collect / (ray1["collect_steps"] / (len(TASKS) * args.demos))
    shares = {
        kind: (sim / wall, work / wall, 1 - (sim + work) / wall) for kind, (wall, sim, work) in split.items()
    }
    # The least any loop runs per step: the simulator plus that work (the rate if nothing else took time).
    floor = {kind: sim / (sim + work) for kind, (_, sim, work) in split.items()}  # of the raw rate
    lines += [
        "",
        "With 2 workers on 2 cores the driver process shares the cores with them (their raw rates drop with it).",
        "",
        "Where the local loop's time goes (a run of its own, the same numbers of episodes from other seeds): "
        f"evaluation: the simulator {100 * shares['eval'][0]:.1f} %, the policy (preprocessing, chunk inference, "
        f"postprocessing) {100 * shares['eval'][1]:.1f} %, the rest {100 * shares['eval'][2]:.1f} % (restores, our env "
        f"and its batching, bookkeeping); collection: the simulator {100 * shares['collect'][0]:.1f} %, the expert's "
        f"action function {100 * shares['collect'][1]:.1f} %, the rest {100 * shares['collect'][2]:.1f} % (restores, "
        "recording, our env). Against the simulator plus that work, the least any loop runs (its rate: evaluation "
        f"{floor['eval']:.2f}x, collection {floor['collect']:.2f}x the raw rate): local evaluation "
        f"{ev_local / raw_rate / floor['eval']:.2f}x and collection {co_local / raw_rate / floor['collect']:.2f}x; "
        f"one Ray worker {ray1_eval / ray1['raw_rate'] / floor['eval']:.2f}x and "
        f"{ray1_collect / ray1['raw_rate'] / floor['collect']:.2f}x ({ray1_shards / ray1['raw_rate'] / floor['collect']:.2f}x "
        "writing shards), taking the work's share of a step to be the local one's.",
        "",
        f"- Ray fixed cost per command (start a local Ray, create the actors, load the policy in each): "
        f"{fixed[1]:.1f} s with 1 worker, {fixed[2]:.1f} s with 2; then writing each worker's first shard of each "
        "task (its first one imports the writer), before the timed shard-writing collection: "
        f"{rows[1][2]['shard_warm_up_seconds']:.2f} s with 1 worker, {rows[2][2]['shard_warm_up_seconds']:.2f} s "
        "with 2.",
        f"- Ray cost per unit against local, 1 worker: {1000 * per_episode:+.1f} ms per evaluation episode (in batches "
        f"of 10), {1000 * per_demo:+.1f} ms per expert episode.",
        "",
        "## The driver's work per collected demonstration, and the ceiling it sets",
        "",
        "Measured with 2 workers, results fetched once they are all ready (the transfer alone, not the wait), "
        "commits of 10:",
        "",
        "| | journal line (synced per commit) | fetch a result | write it into the dataset | driver ms per demonstration |",
        "| --- | --- | --- | --- | --- |",
        f"| frames to the driver, appended there (`--ray.worker_writes=false`) | {1000 * driver['journal_s']:.2f} | "
        f"{1000 * driver['fetch_s']:.2f} | {1000 * driver['append_s']:.1f} | {1000 * per_demo_append_s:.1f} |",
        f"| the worker writes a shard, the driver merges it at each commit | {1000 * driver['journal_s']:.2f} | "
        f"{1000 * driver['fetch_shard_s']:.2f} | {1000 * driver['merge_s']:.1f} | {1000 * per_demo_merge_s:.1f} |",
        f"| the worker writes a shard, a commit journals it, merges of {MERGE_EVERY} written by a worker (default; "
        "driver CPU time) | "
        f"{1000 * driver['journal_s']:.2f} | {1000 * driver['fetch_shard_s']:.2f} | {1000 * driver['round_s']:.2f} | "
        f"{1000 * per_demo_round_s:.2f} |",
        "",
        f"The last row's commits and merges took {1000 * driver['round_wall_s']:.2f} ms of wall time per "
        f"demonstration, {driver['shards']} demonstrations merged in {-(-driver['shards'] // MERGE_EVERY)} "
        "merges: the driver waits for the last merge's files at the round's end; before that, a merge is "
        "committed once a worker has written it, and the round goes on meanwhile.",
        "",
        f"One Ray worker collects {demos_per_s:.1f} demonstrations/s here (recorded, not written). A driver at "
        f"{1000 * per_demo_round_s:.2f} ms per demonstration keeps up with about "
        f"{1 / per_demo_round_s / demos_per_s:.0f} such workers (merging at each commit: "
        f"{1 / per_demo_merge_s / demos_per_s:.0f}; appending on the driver: "
        f"{1 / per_demo_append_s / demos_per_s:.1f}); each worker then also spends the time to write its shards "
        "(benchmarks/results/shard_merge.md). Evaluation-only work (a journal line per episode) scales much further.",
        "",
        f"The workers' side, the same 2 workers collecting {4 * args.demos} push-v3 demonstrations (submit to all "
        f"ready): {driver['frames_rate']:.1f} demonstrations/s when the frames come back to the driver, "
        f"{driver['shards_rate']:.1f}/s when each worker also writes its shard: the write the driver no longer does "
        "is paid on the workers, in parallel.",
        "",
        "`ray, 2 nodes`: a two-node Ray cluster on this machine (`ray.cluster_utils.Cluster`, one CPU per node, one "
        "worker on each), so results and shards cross a node boundary; same results as local.",
    ]
    (RESULTS / "loop_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
