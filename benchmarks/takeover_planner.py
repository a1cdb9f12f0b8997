"""Can the planner finish where the scripted expert fails, from the states a failing policy leaves behind?

    python benchmarks/takeover_planner.py --run_dir RUN/base [--tasks pick-place-v3,peg-insert-side-v3] \
        [--episodes 40] [--planner samples=16,horizon=8]

For each task: the run's round-0 policy is evaluated on `--episodes` of round 1's expansion states; at every failed
rollout the default takeover rule (disagreement with the scripted expert, `TakeoverArgs()`) picks the takeover
state, and from that same state the scripted expert and the planner each get one attempt with the whole step limit
(as `--demo_start=takeover` gives a correction). Reported per task: how often each finishes, the two combined (the
scripted expert first, the planner where it failed), the frames of a correction, and the planner's wall seconds.
Writes benchmarks/results/takeover_planner.md (or `--out`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _common import RESULTS, machine_line, planner_config

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.collectors.takeover import TakeoverArgs, choose_takeover
from adademo_lerobot.core.seeds import expansion_state_seed
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.metadata import load_suite_config
from adademo_lerobot.evaluation.policy import load_policy
from adademo_lerobot.evaluation.rollouts import BatchedEvaluator
from adademo_lerobot.suites import make_suite

ONE_ATTEMPT = TakeoverArgs(attempts=1, fallback="none")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run_dir", type=Path, required=True)
    parser.add_argument("--tasks", default="pick-place-v3,peg-insert-side-v3")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0, help="the run's seed (its expansion states)")
    parser.add_argument("--planner", default="samples=16,horizon=8", help="the planner's fields")
    parser.add_argument("--out", default="takeover_planner.md")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    suite = make_suite(load_suite_config(args.run_dir / "dataset"))
    checkpoint = args.run_dir / "train" / "round-0" / "checkpoints" / "last" / "pretrained_model"
    evaluator = BatchedEvaluator(suite, load_policy(checkpoint), batch_size=10)
    scripted = make_collector(ScriptedCollectorConfig(max_attempts=1), suite)
    planner_fields = planner_config(args.planner, max_attempts=1)
    planner = make_collector(planner_fields, suite)
    started = time.perf_counter()
    rows = []
    for task in args.tasks.split(","):
        seeds = [expansion_state_seed(args.seed, 1, task, k) for k in range(args.episodes)]
        failed = [(r, tr) for r, tr in evaluator.run_traced(task, seeds) if not r.success]
        outcome = {"scripted": [], "planner": []}  # per failed rollout: frames of the correction, or None
        spent = {"scripted": [], "planner": []}  # per failed rollout: expert steps, failed attempts included
        steps, planner_seconds = [], 0.0
        for record, trace in failed:
            point = choose_takeover(trace, TakeoverArgs(), scripted.expert_first_action(task))
            steps.append(point.step)
            for name, collector in (("scripted", scripted), ("planner", planner)):
                began = time.perf_counter()
                result = collector.collect(
                    task, np.asarray(record.initial_state), record.seed, point.state, ONE_ATTEMPT
                )
                if name == "planner":
                    planner_seconds += time.perf_counter() - began
                demo = result.demonstration
                outcome[name].append(None if demo is None else len(demo.frames))
                spent[name].append(result.env_steps)
        both = "scripted, then the planner"
        outcome[both] = [
            s if s is not None else p for s, p in zip(outcome["scripted"], outcome["planner"], strict=True)
        ]
        # the planner acts only after the scripted attempt failed, which spent its steps first
        spent[both] = [
            s + (p if f is None else 0)
            for s, p, f in zip(spent["scripted"], spent["planner"], outcome["scripted"], strict=True)
        ]
        rows.append(
            [
                task,
                f"{len(failed)}/{len(seeds)}",
                f"{np.mean(steps):.0f}" if steps else "-",
                *(finished(outcome[name]) for name in outcome),
                *(mean_frames(outcome[name]) for name in ("scripted", "planner")),
                *(per_correction(spent[name], outcome[name]) for name in outcome),
                f"{planner_seconds / max(1, len(failed)):.1f}",
            ]
        )
        print(task, "done", f"{time.perf_counter() - started:.0f} s", flush=True)
    text = (
        "# The planner as the takeover expert on MetaWorld's weak tasks\n\n"
        f"Command: `python benchmarks/takeover_planner.py --run_dir {args.run_dir} --tasks {args.tasks} "
        f"--episodes {args.episodes} --seed {args.seed} --planner {args.planner}`; {machine_line()}; "
        f"{time.perf_counter() - started:.0f} s in all.\n"
        f"Policy: round 0 of `{args.run_dir}`; states: round 1's first {args.episodes} expansion states per task. "
        "At each failed rollout the default takeover rule (disagreement with the scripted expert) picks the "
        "state; from it each expert gets one attempt with the whole step limit. 'Scripted, then the planner': "
        "the planner only where the scripted expert failed (the collector's `--collector.scripted_first=true`); "
        "its expert steps include the failed scripted attempt's (the whole step limit). "
        f"Planner: {planner_fields}.\n\n"
        + table(
            [
                "task",
                "failed rollouts",
                "mean takeover step",
                "scripted finishes",
                "planner finishes",
                "scripted, then the planner",
                "frames per correction: scripted",
                "planner",
                "expert steps per correction made, failed attempts included: scripted",
                "planner",
                "scripted, then the planner",
                "planner wall s per attempt",
            ],
            rows,
        )
        + "\n"
    )
    (RESULTS / args.out).write_text(text)
    print(text)


def finished(frames: list[int | None]) -> str:
    done = sum(f is not None for f in frames)
    return f"{done}/{len(frames)} ({100.0 * done / len(frames):.0f} %)" if frames else "-"


def per_correction(steps: list[int], frames: list[int | None]) -> str:
    made = sum(f is not None for f in frames)
    return f"{sum(steps) / made:.0f}" if made else "-"


def mean_frames(frames: list[int | None]) -> str:
    done = [f for f in frames if f is not None]
    return f"{np.mean(done):.0f}" if done else "-"


if __name__ == "__main__":
    main()
