"""Success of a suite's experts over seeded random initial states (prints a markdown table).

    ~/.venvs/adademo-lerobot/bin/python benchmarks/expert_success.py --suite fetch     # 100 states per task
    ~/.venvs/adademo-lerobot/bin/python benchmarks/expert_success.py --suite adroit --states 20 --tasks door
    ~/.venvs/adademo-lerobot/bin/python benchmarks/expert_success.py --suite adroit --tasks pen,hammer \
        --collector planner --planner samples=32,threads=2       # the planning expert, with its fields

Initial states are `suite.sample_initial_state(task, seed)` for seeds 0..states-1; each is given to the
collector once (`max_attempts=1`, so no retries with action noise) within the suite's step limit (by default the
envs' own: Fetch 50, Adroit 200, MetaWorld 300). Success is the suite's own rule (`info["is_success"]`; Adroit:
DAPG's, goal achieved on more than 25 steps, Pen 20). Adroit Hammer has no scripted expert; the planner
(`--collector planner`) acts on every task of a suite with full-state restore. Wall seconds are the whole
command's on one process (per demonstration: the task's wall seconds, failed attempts included, over its
successes; torch and OpenMP at 1 thread: set OMP_NUM_THREADS=1 beside other jobs).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import planner_config

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.suites import SuiteConfig, make_suite

DEFAULTS = {  # suite -> (tasks, max_episode_steps, title)
    "fetch": ("reach,push,pick_and_place,slide", 50, "Fetch"),
    "adroit": ("door,pen,relocate", 200, "Adroit"),
    "metaworld": ("mt10", 300, "MetaWorld"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", choices=sorted(DEFAULTS), required=True)
    parser.add_argument("--tasks", help="comma-separated tasks (default: every task with a scripted expert)")
    parser.add_argument("--states", type=int, default=100, help="initial states per task (seeds 0..states-1)")
    parser.add_argument("--max_attempts", type=int, default=1)
    parser.add_argument("--max_episode_steps", type=int)
    parser.add_argument("--collector", choices=["scripted", "planner"], default="scripted")
    parser.add_argument("--planner", default="", help="the planner's fields: samples=32,horizon=12,...")
    args = parser.parse_args()
    default_tasks, default_steps, title = DEFAULTS[args.suite]
    args.tasks = args.tasks or default_tasks
    args.max_episode_steps = args.max_episode_steps or default_steps

    import adademo_lerobot.suites  # noqa: F401  (registers the suite configs)

    config = SuiteConfig.get_choice_class(args.suite)(
        tasks=args.tasks, max_episode_steps=args.max_episode_steps
    )
    suite = make_suite(config)
    if args.collector == "planner":
        config = planner_config(args.planner, max_attempts=args.max_attempts)
    else:
        config = ScriptedCollectorConfig(max_attempts=args.max_attempts)
    collector = make_collector(config, suite)
    rows = []
    for task in suite.tasks:
        started = time.perf_counter()
        successes, demo_frames, env_steps, failed = 0, [], 0, []
        for seed in range(args.states):
            result = collector.collect(task, suite.sample_initial_state(task, seed), seed)
            env_steps += result.env_steps
            if result.demonstration is not None:
                successes += 1
                demo_frames.append(len(result.demonstration.frames))
            else:
                failed.append(seed)
        seconds = time.perf_counter() - started
        mean_frames = f"{np.mean(demo_frames):.1f}" if demo_frames else "-"
        shown = ", ".join(map(str, failed[:10])) + (" ..." if len(failed) > 10 else "")
        rows.append(
            (
                task,
                f"{successes}/{args.states}",
                f"{100.0 * successes / args.states:.0f}%",
                mean_frames,
                str(env_steps),
                f"{seconds:.1f}",
                f"{seconds / successes:.1f}" if successes else "-",
                shown or "-",
            )
        )

    header = (
        "task",
        "successes",
        "success rate",
        "mean demo frames",
        "env steps",
        "wall s",
        "wall s per demonstration",
        "failed seeds",
    )
    expert = "scripted experts" if args.collector == "scripted" else f"planner ({config})"
    print(
        f"{title} {expert}, seeds 0..{args.states - 1}, max_attempts={args.max_attempts}, "
        f"max_episode_steps={args.max_episode_steps}\n"
    )
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
