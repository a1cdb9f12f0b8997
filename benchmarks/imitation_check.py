"""Is a task's failure in the data or in the imitation? Two checks on a finished round of a run, per task:

- replay: each of the first demonstrations' recorded actions, stepped from its recorded initial state (its
  `adademo/seed`) in the suite's env: a demonstration that does not succeed again means the data, the env or the
  restore is wrong;
- training states: the round's policy, run closed-loop (as the evaluation runs it) from the initial states of the
  same demonstrations it was trained on: failing there is not generalization, the policy does not reproduce its
  own training data.

    python benchmarks/imitation_check.py --run_dir RUN [--round 0] [--episodes 20]
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


def check(run_dir: Path, round_index: int, per_task: int) -> str:
    dataset = run_dir / "dataset"
    suite = suite_config_from_dict(
        json.loads((dataset / "meta" / "adademo" / "suite.json").read_text())
    ).build()
    episodes = [
        e for e in read_parquets(dataset / "meta" / "episodes").to_pylist() if e["adademo/round"] == 0
    ]
    frames = read_parquets(dataset / "data", ["episode_index", "action"])
    index = np.asarray(frames.column("episode_index").to_pylist())
    actions = np.asarray(frames.column("action").to_pylist(), dtype=np.float32)
    state = json.loads((run_dir / "run_state.json").read_text())
    evaluator = BatchedEvaluator(suite, load_policy(state["done"][f"train-{round_index}"]["result"]))
    rows = []
    for task in suite.tasks:
        mine = [e for e in episodes if e["tasks"] == [task]][:per_task]
        actions_of = {e["episode_index"]: actions[index == e["episode_index"]] for e in mine}
        replayed = replays_succeed(suite, task, mine, actions_of)
        closed_loop = sum(r.success for r in evaluator.run(task, [int(e["adademo/seed"]) for e in mine]))
        rows.append([task, len(mine), f"{replayed}/{len(mine)}", f"{closed_loop}/{len(mine)}"])
    headers = [
        "task",
        "first demonstrations",
        "replayed, succeed",
        f"round-{round_index} policy from their states",
    ]
    return table(headers, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run_dir", type=Path, required=True)
    parser.add_argument("--round", type=int, default=0, help="whose trained policy runs (default: round 0)")
    parser.add_argument("--episodes", type=int, default=20, help="first demonstrations per task checked")
    args = parser.parse_args()
    torch.set_num_threads(1)  # as the evaluation runs policies
    print(f"{machine_line()}; run {args.run_dir}, round {args.round}")
    print(check(args.run_dir, args.round, args.episodes))


if __name__ == "__main__":
    main()
