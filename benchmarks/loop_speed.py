"""Env steps per second of evaluation and expert collection against raw simulator stepping.

    python benchmarks/loop_speed.py [--seconds 20]

Same MetaWorld tasks, same run: (1) raw stepping of the bare MetaWorld env with random actions, (2) our
`BatchedEvaluator` (LeRobot rollout + a small ACT, batch 10), (3) scripted expert collection. Each is measured
with 1 and with 2 worker processes running at once (torch threads 1 per worker); throughput is the sum over
workers. Writes benchmarks/results/loop_speed.md.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import RESULTS, collect, machine_line, train_small_act

TASKS = ["reach-v3", "push-v3", "drawer-open-v3", "pick-place-v3"]


def raw_worker(seconds: float, seed: int, q) -> None:
    from adademo_lerobot.suites.metaworld import make_raw_env

    rng = np.random.default_rng(seed)
    envs = {t: make_raw_env(t) for t in TASKS}
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _t, env in envs.items():
            env._freeze_rand_vec = False
            env.seeded_rand_vec = True
            env.seed(int(rng.integers(1 << 30)))
            env.reset()
            for _ in range(200):
                env.step(rng.uniform(-1, 1, 4).astype(np.float32))
            steps += 200
    q.put((steps, time.perf_counter() - start))


def eval_worker(seconds: float, seed: int, ckpt: str, q) -> None:
    import torch

    torch.set_num_threads(1)
    from adademo_lerobot.evaluation import BatchedEvaluator
    from adademo_lerobot.policy import load_policy
    from adademo_lerobot.seeds import evaluation_seeds
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS), max_episode_steps=200))
    evaluator = BatchedEvaluator(suite, load_policy(ckpt), batch_size=10)
    evaluator.run(
        TASKS[0], evaluation_seeds(seed, TASKS[0], 10)
    )  # warm-up: first inference outside the clock
    evaluator.env_steps = 0
    start, k = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        for t in TASKS:  # 50 episodes per task per call, as adademo-eval runs them (env batch built per task)
            evaluator.run(t, evaluation_seeds(seed + 1000 * k, t, 50))
        k += 1
    q.put((evaluator.env_steps, time.perf_counter() - start))


def collect_worker(seconds: float, seed: int, q) -> None:
    from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
    from adademo_lerobot.seeds import derive_seed
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS), max_episode_steps=200))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    steps, start, k = 0, time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        for t in TASKS:
            s = derive_seed(seed, t, k)
            steps += collector.collect(t, suite.sample_initial_state(t, s), s).env_steps
        k += 1
    q.put((steps, time.perf_counter() - start))


def measure(target, workers: int, *args) -> float:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    procs = [ctx.Process(target=target, args=(*args[:1], 7 + i, *args[1:], q)) for i in range(workers)]
    for p in procs:
        p.start()
    results = [q.get() for _ in procs]
    for p in procs:
        p.join()
    return sum(steps / secs for steps, secs in results)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=20)
    args = parser.parse_args()
    os.environ["OMP_NUM_THREADS"] = "1"
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = str(
            train_small_act(collect(Path(tmp) / "ds", ",".join(TASKS), 3), Path(tmp) / "train", steps=20)
        )
        rows = []
        for workers in (1, 2):
            raw = measure(raw_worker, workers, args.seconds)
            ev = measure(eval_worker, workers, args.seconds, ckpt)
            col = measure(collect_worker, workers, args.seconds)
            rows.append((workers, raw, ev, col))
            print(
                f"workers={workers}: raw {raw:.0f}, eval {ev:.0f}, collection {col:.0f} steps/s", flush=True
            )
    r1 = rows[0]
    lines = [
        "# Loop speed: evaluation and collection vs raw simulator stepping",
        "",
        f"Command: `python benchmarks/loop_speed.py --seconds {args.seconds:g}`; {machine_line()}.",
        f"Tasks: {', '.join(TASKS)} (state observations, 200-step episodes). Raw = bare MetaWorld env with random",
        "actions. Eval = `BatchedEvaluator` (LeRobot `rollout()`, SyncVectorEnv of 10, small ACT from",
        "`policies/act_state_cpu.yaml`, torch threads 1 per worker, 50 episodes per task per call as `adademo-eval`",
        "runs them, building each task's batch of envs in the clock). Collection = MetaWorld scripted experts with",
        "recording, one episode per task in turn. Throughput summed over worker processes running at the same time.",
        "Raw resets the stock env every 200 steps; evaluation and collection episodes end at success (often after",
        "50-100 steps), so they pay for a reset more often.",
        "",
        "| workers | raw steps/s | eval steps/s | eval / raw | collection steps/s | collection / raw |",
        "| --- | --- | --- | --- | --- | --- |",
        *[
            f"| {w} | {raw:.0f} | {ev:.0f} | {ev / raw:.2f} | {col:.0f} | {col / raw:.2f} |"
            for w, raw, ev, col in rows
        ],
        "",
        f"Scaling from 1 to 2 workers: raw x{rows[1][1] / r1[1]:.2f}, eval x{rows[1][2] / r1[2]:.2f}, "
        f"collection x{rows[1][3] / r1[3]:.2f}.",
    ]
    (RESULTS / "loop_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
