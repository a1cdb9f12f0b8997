"""Is a task's failure in the data or in the imitation? Two checks on a finished round of a run, per task:

- replay: each of the first demonstrations' recorded actions, stepped from its recorded initial state (its
  `adademo/seed`) in the suite's env: a demonstration that does not succeed again means the data, the env or the
  restore is wrong;
- training states: the round's policy, run closed-loop (as the evaluation runs it) from the initial states of the
  same demonstrations it was trained on: failing there is not generalization, the policy does not reproduce its
  own training data.

A third column runs the policy from new initial states (seeds it was not trained on), for comparison.

    python benchmarks/imitation_check.py --run_dir RUN [--round 0] [--episodes 20] [--new_states 20]
    python benchmarks/imitation_check.py --dataset DATASET_ROOT --policy CHECKPOINT/pretrained_model
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from _common import machine_line

from adademo_lerobot.core.tables import table
from adademo_lerobot.evaluation.policy import load_policy
from adademo_lerobot.evaluation.rollouts import BatchedEvaluator
from adademo_lerobot.suites import suite_config_from_dict

# New initial states: seeds 1000, 1001, ... (collection seeds are 64-bit hashes of the run's seed, never these).
NEW_STATE_SEEDS = 1000


def read_parquets(folder: Path, columns: list[str] | None = None) -> pa.Table:
    return pa.concat_tables(pq.read_table(p, columns=columns) for p in sorted(folder.glob("*/*.parquet")))


def replays_succeed(suite, task: str, episodes: list[dict], actions_of: dict[int, np.ndarray]) -> int:
    env = suite.make_env(task)
    succeeded = 0
    for episode in episodes:
        env.reset(seed=int(episode["adademo/seed"]))
        for action in actions_of[episode["episode_index"]]:
            _, _, terminated, truncated, info = env.step(action)
            if info.get("is_success"):
                succeeded += 1
                break
            if terminated or truncated:
                break
    env.close()
    return succeeded


def check(dataset: Path, policy: str, per_task: int, new_states: int) -> str:
    suite = suite_config_from_dict(
        json.loads((dataset / "meta" / "adademo" / "suite.json").read_text())
    ).build()
    episodes = [
        e for e in read_parquets(dataset / "meta" / "episodes").to_pylist() if e["adademo/round"] == 0
    ]
    frames = read_parquets(dataset / "data", ["episode_index", "action"])
    index = np.asarray(frames.column("episode_index").to_pylist())
    actions = np.asarray(frames.column("action").to_pylist(), dtype=np.float32)
    evaluator = BatchedEvaluator(suite, load_policy(policy))
    rows = []
    for task in suite.tasks:
        mine = [e for e in episodes if e["tasks"] == [task]][:per_task]
        actions_of = {e["episode_index"]: actions[index == e["episode_index"]] for e in mine}
        replayed = replays_succeed(suite, task, mine, actions_of)
        trained_on = sum(r.success for r in evaluator.run(task, [int(e["adademo/seed"]) for e in mine]))
        new = sum(r.success for r in evaluator.run(task, [NEW_STATE_SEEDS + i for i in range(new_states)]))
        rows.append(
            [task, len(mine), f"{replayed}/{len(mine)}", f"{trained_on}/{len(mine)}", f"{new}/{new_states}"]
        )
    headers = [
        "task",
        "first demonstrations",
        "replayed, succeed",
        "policy from their initial states",
        "policy from new initial states",
    ]
    return table(headers, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run_dir", type=Path, help="a run folder: its dataset and a round's policy")
    parser.add_argument(
        "--round", type=int, default=0, help="--run_dir: whose policy runs (default: round 0)"
    )
    parser.add_argument("--dataset", type=Path, help="instead of --run_dir: a dataset root (adademo's)")
    parser.add_argument("--policy", help="with --dataset: a checkpoint's pretrained_model folder")
    parser.add_argument("--episodes", type=int, default=20, help="first demonstrations per task checked")
    parser.add_argument("--new_states", type=int, default=20, help="new initial states per task")
    args = parser.parse_args()
    if args.run_dir is not None:
        state = json.loads((args.run_dir / "run_state.json").read_text())
        dataset, policy = args.run_dir / "dataset", state["done"][f"train-{args.round}"]["result"]
    elif args.dataset is not None and args.policy is not None:
        dataset, policy = args.dataset, args.policy
    else:
        parser.error("give --run_dir, or --dataset and --policy")
    torch.set_num_threads(1)  # as the evaluation runs policies
    print(f"{machine_line()}; dataset {dataset}, policy {policy}")
    print(check(dataset, policy, args.episodes, args.new_states))


if __name__ == "__main__":
    main()
