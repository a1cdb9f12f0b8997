"""Where do failed rollouts go wrong, and can the expert take over there? A look at a real round-0 policy.

    python benchmarks/takeover_pilot.py --run_dir ~/adademo-bench/seed0/base [--episodes 20]

For each task of the run's suite: the round-0 policy is evaluated on `--episodes` expansion-round states (the
states round 1 would see), and for every failed rollout, per takeover rule setting: the step it picks, whether
the scripted expert finishes the task from there (retries included, as a collection does), and the correction's
length against a demonstration from the initial state. Writes benchmarks/results/takeover_pilot.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _common import RESULTS, machine_line

from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
from adademo_lerobot.collectors.takeover import TakeoverArgs, choose_takeover
from adademo_lerobot.core.seeds import expansion_state_seed
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.metadata import load_suite_config
from adademo_lerobot.evaluation.policy import load_policy
from adademo_lerobot.evaluation.rollouts import BatchedEvaluator
from adademo_lerobot.suites import make_suite

# Every setting gets 3 attempts and no fallback here, to see what retries from the same state are worth.
ATTEMPTS = 3
SETTINGS = {
    "initial (the paper)": None,
    "disagreement 0.5 x3 -5": TakeoverArgs("disagreement", 0.5, 3, 5),
    "disagreement 1.0 x5 -5": TakeoverArgs("disagreement", 1.0, 5, 5),
    "disagreement 1.0 x10 -5": TakeoverArgs("disagreement", 1.0, 10, 5),
    "disagreement 1.5 x5 -5": TakeoverArgs("disagreement", 1.5, 5, 5),
    "disagreement 1.5 x5 -10 (the default)": TakeoverArgs("disagreement", 1.5, 5, 10),
    "backoff -5": TakeoverArgs("backoff", backoff=5),
    "backoff -20": TakeoverArgs("backoff", backoff=20),
    "backoff -50": TakeoverArgs("backoff", backoff=50),
}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--run_dir", type=Path, required=True)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    suite = make_suite(load_suite_config(args.run_dir / "dataset"))
    checkpoint = args.run_dir / "train" / "round-0" / "checkpoints" / "last" / "pretrained_model"
    evaluator = BatchedEvaluator(suite, load_policy(checkpoint), batch_size=10)
    collector = make_collector(ScriptedCollectorConfig(), suite)
    rows = []
    per = {
        name: {"failures": 0, "expert_ok": 0, "retry_ok": 0, "steps": [], "frames": [], "rules": []}
        for name in SETTINGS
    }
    started = time.perf_counter()
    for task in suite.tasks:
        seeds = [expansion_state_seed(args.seed, 1, task, k) for k in range(args.episodes)]
        traced = evaluator.run_traced(task, seeds)
        failed = [(r, tr) for r, tr in traced if not r.success]
        for name, setting in SETTINGS.items():
            stats = {"ok": 0, "steps": [], "frames": []}
            for record, trace in failed:
                if setting is None:
                    start, step = None, 0
                else:
                    point = choose_takeover(trace, setting, collector.expert_first_action(task))
                    start, step = point.state, point.step
                    per[name]["rules"].append(point.rule)
                attempts = TakeoverArgs(attempts=ATTEMPTS, fallback="none")
                result = collector.collect(
                    task, np.asarray(record.initial_state), record.seed, start, attempts
                )
                if result.demonstration is not None:
                    stats["ok"] += 1
                    per[name]["retry_ok"] += result.attempts > 1
                    stats["frames"].append(len(result.demonstration.frames))
                stats["steps"].append(step)
            per[name]["failures"] += len(failed)
            per[name]["expert_ok"] += stats["ok"]
            per[name]["steps"] += stats["steps"]
            per[name]["frames"] += stats["frames"]
            rows.append(
                [
                    task,
                    name,
                    f"{len(failed)}/{len(traced)}",
                    f"{stats['ok']}/{len(failed)}",
                    f"{np.mean(stats['steps']):.0f}" if stats["steps"] else "-",
                    f"{np.mean(stats['frames']):.0f}" if stats["frames"] else "-",
                ]
            )
        print(task, "done", f"{time.perf_counter() - started:.0f} s", flush=True)
    totals = [
        [
            name,
            f"{p['expert_ok']}/{p['failures']}",
            f"{p['retry_ok']}/{p['failures'] - p['expert_ok'] + p['retry_ok']}",
            f"{np.mean(p['steps']):.0f}" if p["steps"] else "-",
            f"{np.mean(p['frames']):.0f}" if p["frames"] else "-",
            f"{p['rules'].count('disagreement')}/{len(p['rules'])}" if p["rules"] else "-",
        ]
        for name, p in per.items()
    ]
    text = (
        "# Takeover pilot: where failed rollouts go wrong and whether the expert can take over there\n\n"
        f"Command: `python benchmarks/takeover_pilot.py --run_dir {args.run_dir} --episodes {args.episodes}`; "
        f"{machine_line()}; {time.perf_counter() - started:.0f} s.\n"
        f"Policy: round 0 of {args.run_dir.name} (the data-efficiency recipe); states: round 1's first "
        f"{args.episodes} expansion states per task. Settings: rule threshold x consecutive -backoff. Every "
        "correction gets the whole step limit from its takeover state.\n\n"
        f"All tasks (the expert gets {ATTEMPTS} attempts, the 2nd and 3rd with seeded action noise; 'on a retry': "
        "of the states the first attempt failed from, those a later attempt finished):\n\n"
        + table(
            [
                "setting",
                "expert finishes",
                "on a retry",
                "mean takeover step",
                "mean demo frames",
                "by disagreement",
            ],
            totals,
        )
        + "\n\nPer task:\n\n"
        + table(
            ["task", "setting", "failed", "expert finishes", "mean takeover step", "mean demo frames"], rows
        )
        + "\n"
    )
    (RESULTS / "takeover_pilot.md").write_text(text)
    (RESULTS / "takeover_pilot.json").write_text(
        json.dumps({k: {**v, "rules": None} for k, v in per.items()}, default=float)
    )
    print(text)


if __name__ == "__main__":
    main()
