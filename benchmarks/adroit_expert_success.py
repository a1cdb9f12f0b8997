"""Success of the Adroit scripted experts over seeded random initial states (prints a markdown table).

    ~/.venvs/adademo-lerobot/bin/python benchmarks/adroit_expert_success.py            # 100 states per task
    ~/.venvs/adademo-lerobot/bin/python benchmarks/adroit_expert_success.py --states 20 --tasks door

Initial states are `suite.sample_initial_state(task, seed)` for seeds 0..states-1; each is given to the
collector once (`max_attempts=1`, so no retries with action noise) within the suite's step limit (default 200,
the Adroit envs' own). Success is the suite's rule (DAPG): the env's goal achieved on more than 25 steps (Pen:
20) of the episode. Hammer has no scripted expert and is not measured.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from adademo_lerobot.collectors.base import ScriptedCollectorConfig, make_collector
from adademo_lerobot.suites.adroit import AdroitSuiteConfig
from adademo_lerobot.suites.base import make_suite


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="door,pen,relocate")
    parser.add_argument("--states", type=int, default=100, help="initial states per task (seeds 0..states-1)")
    parser.add_argument("--max_attempts", type=int, default=1)
    parser.add_argument("--max_episode_steps", type=int, default=200)
    args = parser.parse_args()

    suite = make_suite(AdroitSuiteConfig(tasks=args.tasks, max_episode_steps=args.max_episode_steps))
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

    header = ("task", "successes", "success rate", "mean demo frames", "env steps", "wall s", "failed seeds")
    print(f"Adroit scripted experts, seeds 0..{args.states - 1}, max_attempts={args.max_attempts}, "
          f"max_episode_steps={args.max_episode_steps}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
