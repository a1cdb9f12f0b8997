"""Success of the Fetch scripted experts over seeded random initial states (prints a markdown table).

    ~/.venvs/adademo-lerobot/bin/python benchmarks/fetch_expert_success.py            # 100 states per task
    ~/.venvs/adademo-lerobot/bin/python benchmarks/fetch_expert_success.py --states 20 --tasks reach,push

Initial states are `suite.sample_initial_state(task, seed)` for seeds 0..states-1; each is given to the
collector once (`max_attempts=1`, so no retries with action noise) within the suite's step limit (default 50).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from adademo_lerobot.collectors.base import ScriptedCollectorConfig, make_collector
from adademo_lerobot.suites.base import make_suite
from adademo_lerobot.suites.fetch import FetchSuiteConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="reach,push,pick_and_place,slide")
    parser.add_argument("--states", type=int, default=100, help="initial states per task (seeds 0..states-1)")
    parser.add_argument("--max_attempts", type=int, default=1)
    parser.add_argument("--max_episode_steps", type=int, default=50)
    args = parser.parse_args()

    suite = make_suite(FetchSuiteConfig(tasks=args.tasks, max_episode_steps=args.max_episode_steps))
    collector = make_collector(ScriptedCollectorConfig(max_attempts=args.max_attempts), suite)
    rows = []
    for task in suite.tasks:
        started = time.perf_counter()
        successes, demo_frames, env_steps, failed = 0, [], 0, []
        for seed in range(args.states):
            result = collector.collect(task, suite.sample_initial_state(task, seed), seed)
            env_steps += result.env_steps
            if result.succeeded:
                successes += 1
                demo_frames.append(len(result.demonstration.frames))
            else:
                failed.append(seed)
        seconds = time.perf_counter() - started
        mean_frames = f"{np.mean(demo_frames):.1f}" if demo_frames else "-"
        shown = ", ".join(map(str, failed[:10])) + (" ..." if len(failed) > 10 else "")
        rows.append((task, f"{successes}/{args.states}", f"{100.0 * successes / args.states:.0f}%", mean_frames,
                     str(env_steps), f"{seconds:.1f}", shown or "-"))

    header = ("task", "successes", "success rate", "mean demo frames", "env steps", "wall s",
              "failed seeds")
    print(f"Fetch scripted experts, seeds 0..{args.states - 1}, max_attempts={args.max_attempts}, "
          f"max_episode_steps={args.max_episode_steps}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
