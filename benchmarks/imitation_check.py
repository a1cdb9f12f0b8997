"""Is a task's failure in the data or in the imitation? Two checks on a finished round of a run, per task:

- replay: each of the first demonstrations' recorded actions, stepped from its recorded initial state (its
  `adademo/seed`) in the suite's env: a demonstration that does not succeed again means the data, the env or the
  restore is wrong;
- training states: the round's policy, run closed-loop (as the evaluation runs it) from the initial states of the
  same demonstrations it was trained on: failing there is not generalization, the policy does not reproduce its
  own training data.

A third column runs the policy from new initial states (seeds it was not trained on), for comparison. A fourth,
with no policy at all, asks whether the demonstrations can be imitated: how much of their action variance the
nearest states of the task's other demonstrations explain (near 1: similar states got similar actions; near 0 or
below: each demonstration acted its own way, and a policy trained on all of them averages them); `adademo-report`
shows the same score for every run (`adademo_lerobot/dataset/imitability.py`).

    python benchmarks/imitation_check.py --run_dir RUN [--round 0] [--episodes 20] [--new_states 20]
    python benchmarks/imitation_check.py --dataset DATASET_ROOT [--policy CHECKPOINT/pretrained_model]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from _common import machine_line

from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.imitability import agreement_of, read_actions_and_states
from adademo_lerobot.dataset.layout import COL_ROUND, COL_SEED
from adademo_lerobot.dataset.metadata import load_suite_config, read_episode_metadata
from adademo_lerobot.evaluation.policy import load_policy
from adademo_lerobot.evaluation.rollouts import BatchedEvaluator

# New initial states: seeds 1000, 1001, ... (collection seeds are 64-bit hashes of the run's seed, never these).
NEW_STATE_SEEDS = 1000


def replays_succeed(suite, task: str, replays: list[tuple[int, np.ndarray]]) -> int:
    """How many of the (initial-state seed, recorded actions) episodes reach success when stepped again."""
    env = suite.make_env(task)
    succeeded = 0
    for seed, actions in replays:
        env.reset(seed=seed)
        for action in actions:
            _, _, terminated, truncated, info = env.step(action)
            if info.get("is_success"):
                succeeded += 1
                break
            if terminated or truncated:
                break
    env.close()
    return succeeded


def check(dataset: Path, policy: str | None, per_task: int, new_states: int) -> str:
    """The table; without a policy, only the columns about the data."""
    suite = load_suite_config(dataset).build()
    episodes = read_episode_metadata(dataset)
    first = episodes[episodes[COL_ROUND] == 0]
    actions, states = read_actions_and_states(dataset)
    evaluator = BatchedEvaluator(suite, load_policy(policy)) if policy else None
    rows = []
    for task in suite.tasks:
        mine = first[first["task"] == task].head(per_task)
        seeds = [int(seed) for seed in mine[COL_SEED]]
        frame_ranges = [
            range(start, stop)
            for start, stop in zip(mine["dataset_from_index"], mine["dataset_to_index"], strict=True)
        ]
        replayed = replays_succeed(
            suite,
            task,
            [(seed, actions[f.start : f.stop]) for seed, f in zip(seeds, frame_ranges, strict=True)],
        )
        explained = agreement_of(actions, states, frame_ranges)
        shown = "-" if explained is None else f"{explained:.2f}"
        rows.append([task, len(mine), shown, f"{replayed}/{len(mine)}"])
        if evaluator is not None:
            trained_on = sum(r.success for r in evaluator.run(task, seeds))
            new = sum(
                r.success for r in evaluator.run(task, [NEW_STATE_SEEDS + i for i in range(new_states)])
            )
            rows[-1] += [f"{trained_on}/{len(mine)}", f"{new}/{new_states}"]
    headers = [
        "task",
        "first demonstrations",
        "their actions explained by other demonstrations' nearest states",
        "replayed, succeed",
    ]
    if evaluator is not None:
        headers += ["policy from their initial states", "policy from new initial states"]
    return table(headers, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run_dir", type=Path, help="a run folder: its dataset and a round's policy")
    parser.add_argument(
        "--round", type=int, default=0, help="--run_dir: whose policy runs (default: round 0)"
    )
    parser.add_argument("--dataset", type=Path, help="instead of --run_dir: a dataset root (adademo's)")
    parser.add_argument(
        "--policy",
        help="with --dataset: a checkpoint's pretrained_model folder (without: the data columns only)",
    )
    parser.add_argument("--episodes", type=int, default=20, help="first demonstrations per task checked")
    parser.add_argument("--new_states", type=int, default=20, help="new initial states per task")
    args = parser.parse_args()
    if args.run_dir is not None:
        if not (args.run_dir / "run_state.json").is_file():
            parser.error(f"--run_dir {args.run_dir} is not a run folder (no run_state.json)")
        state = json.loads((args.run_dir / "run_state.json").read_text())
        if f"train-{args.round}" not in state["done"]:
            parser.error(f"--run_dir {args.run_dir} has not trained round {args.round} yet")
        dataset, policy = args.run_dir / "dataset", state["done"][f"train-{args.round}"]["result"]
    elif args.dataset is not None:
        dataset, policy = args.dataset, args.policy
    else:
        parser.error("give --run_dir, or --dataset (and --policy)")
    if not (Path(dataset) / "meta" / "info.json").is_file():
        parser.error(f"{dataset} is not a LeRobot dataset (no meta/info.json)")
    torch.set_num_threads(1)  # as the evaluation runs policies
    print(f"{machine_line()}; dataset {dataset}, policy {policy}")
    print(check(dataset, policy, args.episodes, args.new_states))


if __name__ == "__main__":
    main()
