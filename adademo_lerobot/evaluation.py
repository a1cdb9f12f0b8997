"""Evaluate a LeRobot policy on chosen initial states, batched over vectorized envs.

Each sub-env of a `SyncVectorEnv` is told its initial state through `set_attr("pending_initial_state", ...)`
before LeRobot's own `rollout()` resets the batch, so the policy sees a batch and every episode starts from
exactly the state we asked for.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.patching import temporarily_set
from adademo_lerobot.policy import LoadedPolicy
from adademo_lerobot.records import EpisodeRecord
from adademo_lerobot.seeds import evaluation_seeds
from adademo_lerobot.suites.base import TaskSuite, cached_for_task
from adademo_lerobot.tables import table


def _without_rollout_progress_bar():
    """LeRobot's rollout() draws a bar per batch of envs; ours count episodes instead (logs stay readable)."""
    import lerobot.scripts.lerobot_eval as lerobot_eval

    stock = lerobot_eval.trange
    return temporarily_set(
        lerobot_eval, "trange", lambda *args, **kwargs: stock(*args, **{**kwargs, "disable": True})
    )


class BatchedEvaluator:
    """Runs a policy from given initial states, `batch_size` episodes at a time per task."""

    def __init__(self, suite: TaskSuite, loaded: LoadedPolicy, batch_size: int = 10, progress=None):
        if batch_size < 1:
            raise AdaDemoError(f"--eval.batch_size must be >= 1, got {batch_size}")
        from lerobot.processor import PolicyProcessorPipeline

        self.suite, self.loaded, self.batch_size = suite, loaded, batch_size
        self.progress = progress  # an optional tqdm bar advanced by one per finished episode
        self._identity = PolicyProcessorPipeline(steps=[])
        self._envs: dict[tuple[str, int], object] = {}  # (task, batch size) -> gymnasium SyncVectorEnv
        self.env_steps = 0

    def _vector_env(self, task: str, n: int):
        import gymnasium as gym

        def make():
            env = gym.vector.SyncVectorEnv([lambda: self.suite.make_env(task, terminate_on_success=True)] * n)
            env.set_attr("hold_after_episode", True)  # no simulation after an episode ends
            return env

        # One task's batches at a time (10 envs of ~35 MB each); rebuilding a batch takes < 1 s.
        return cached_for_task(self._envs, (task, n), make, keep=1, task_of=lambda key: key[0])

    def run(self, task: str, seeds: list[int]) -> list[EpisodeRecord]:
        """One episode per seed, from that seed's initial state, in `batch_size` batches; records in seed order."""
        import torch
        from lerobot.scripts.lerobot_eval import rollout

        states = [self.suite.sample_initial_state(task, s) for s in seeds]
        records: list[EpisodeRecord] = []
        for begin in range(0, len(seeds), self.batch_size):
            batch_seeds, batch_states = (
                seeds[begin : begin + self.batch_size],
                states[begin : begin + self.batch_size],
            )
            env = self._vector_env(task, len(batch_seeds))
            env.set_attr("pending_initial_state", [np.asarray(s, dtype=np.float64) for s in batch_states])
            with torch.inference_mode(), _without_rollout_progress_bar():
                out = rollout(
                    env,
                    self.loaded.policy,
                    self._identity,
                    self._identity,
                    self.loaded.preprocessor,
                    self.loaded.postprocessor,
                )
            done = out["done"].numpy()
            success = out["success"].numpy()
            reward = out["reward"].numpy()
            for i, (s, st) in enumerate(zip(batch_seeds, batch_states, strict=True)):
                steps = int(np.argmax(done[i]) + 1) if done[i].any() else done.shape[1]
                self.env_steps += steps
                records.append(
                    EpisodeRecord(
                        task,
                        int(s),
                        np.asarray(st, np.float64).tolist(),
                        bool(success[i, :steps].any()),
                        steps,
                        float(reward[i, :steps].sum()),
                    )
                )
            if self.progress is not None:
                self.progress.update(len(batch_seeds))
                self.progress.set_postfix(task=task, success=f"{np.mean([r.success for r in records]):.0%}")
        return records

    def close(self) -> None:
        for env in self._envs.values():
            env.close()


def evaluate_fixed_set(
    suite: TaskSuite, loaded: LoadedPolicy, seed: int, episodes_per_task: int, batch_size: int
) -> tuple[list[EpisodeRecord], int, float]:
    """Every task on its fixed evaluation states, with one progress bar over episodes.
    Returns (records, env steps, wall seconds)."""
    from tqdm import tqdm

    bar = tqdm(
        total=len(suite.tasks) * episodes_per_task, desc="evaluating", unit="episode", dynamic_ncols=True
    )
    evaluator = BatchedEvaluator(suite, loaded, batch_size, progress=bar)
    start = time.perf_counter()
    records: list[EpisodeRecord] = []
    for task in suite.tasks:
        records += evaluator.run(task, evaluation_seeds(seed, task, episodes_per_task))
    evaluator.close()
    bar.close()
    return records, evaluator.env_steps, time.perf_counter() - start


def success_table(records: list[EpisodeRecord], tasks: list[str]) -> pd.DataFrame:
    df = pd.DataFrame([asdict(r) for r in records])
    rows = []
    for task in tasks:
        sub = df[df.task == task]
        rows.append(
            {
                "task": task,
                "episodes": len(sub),
                "successes": int(sub.success.sum()),
                "success_rate": float(sub.success.mean()) if len(sub) else float("nan"),
                "mean_steps": float(sub.steps.mean()) if len(sub) else float("nan"),
            }
        )
    table = pd.DataFrame(rows)
    avg = {
        "task": "average",
        "episodes": int(table.episodes.sum()),
        "successes": int(table.successes.sum()),
        "success_rate": float(table.success_rate.mean()),
        "mean_steps": float(df.steps.mean()),
    }
    return pd.concat([table, pd.DataFrame([avg])], ignore_index=True)


def format_success_table(success: pd.DataFrame) -> str:
    rows = [
        (r.task, f"{r.successes}/{r.episodes}", f"{100 * r.success_rate:.1f}%", f"{r.mean_steps:.1f}")
        for r in success.itertuples()
    ]
    return table(["task", "success", "rate", "mean steps"], rows)


def write_eval_outputs(
    output_dir: Path, records: list[EpisodeRecord], success: pd.DataFrame, meta: dict
) -> None:
    """`eval_episodes.parquet` and `eval_summary.json`, each written whole (the summary last: it marks done)."""
    from adademo_lerobot.files import atomic_write_text

    output_dir.mkdir(parents=True, exist_ok=True)
    tmp = output_dir / ".eval_episodes.parquet.tmp"
    pd.DataFrame([asdict(r) for r in records]).to_parquet(tmp)
    tmp.replace(output_dir / "eval_episodes.parquet")
    summary = {**meta, "per_task": success.to_dict(orient="records")}
    atomic_write_text(output_dir / "eval_summary.json", json.dumps(summary, indent=2))


def run_eval(cfg) -> pd.DataFrame:
    """`adademo-eval`."""
    from adademo_lerobot.dataset.features import dataset_features
    from adademo_lerobot.dataset.metadata import load_suite_config
    from adademo_lerobot.policy import load_checked_policy
    from adademo_lerobot.suites import make_suite

    if cfg.policy.path is None:
        raise AdaDemoError("--policy.path is required (a LeRobot checkpoint's pretrained_model folder)")
    if cfg.episodes_per_task < 1:
        raise AdaDemoError(f"--episodes_per_task must be >= 1, got {cfg.episodes_per_task}")
    if cfg.output_dir is None:
        raise AdaDemoError("--output_dir is required")
    suite = make_suite(load_suite_config(Path(cfg.dataset.root)) if cfg.dataset.root else cfg.suite)
    import torch

    torch.set_num_threads(cfg.torch_threads)
    loaded = load_checked_policy(cfg.policy.path, dataset_features(suite), cfg.device)
    records, env_steps, elapsed = evaluate_fixed_set(
        suite, loaded, cfg.seed, cfg.episodes_per_task, cfg.eval.batch_size
    )
    success = success_table(records, suite.tasks)
    print(format_success_table(success))
    write_eval_outputs(
        Path(cfg.output_dir),
        records,
        success,
        {
            "policy_path": str(cfg.policy.path),
            "seed": cfg.seed,
            "episodes_per_task": cfg.episodes_per_task,
            "env_steps": env_steps,
            "wall_seconds": elapsed,
            "suite": suite.config.to_dict(),
        },
    )
    print(
        f"{env_steps} env steps in {elapsed:.1f} s ({env_steps / max(elapsed, 1e-9):.0f} steps/s); "
        f"records: {Path(cfg.output_dir) / 'eval_episodes.parquet'}"
    )
    return success
