"""Evaluate a LeRobot policy on chosen initial states, batched over vectorized envs.

Each sub-env of a `SyncVectorEnv` is told its initial state through `set_attr("pending_initial_state", ...)`
before LeRobot's own `rollout()` resets the batch, so the policy sees a batch and every episode starts from
exactly the state we asked for.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np
import pandas as pd

from adademo_lerobot.core.episodes import EpisodeRecord, RolloutTrace, record_row
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.patching import temporarily_set
from adademo_lerobot.core.seeds import derive_seed
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.recorder import RolloutTracer
from adademo_lerobot.evaluation.policy import LoadedPolicy
from adademo_lerobot.suites.base import TaskSuite, cached_for_task


def _without_rollout_progress_bar():
    """LeRobot's rollout() draws a bar per batch of envs; ours count episodes instead (logs stay readable)."""
    import lerobot.scripts.lerobot_eval as lerobot_eval

    stock = lerobot_eval.trange
    return temporarily_set(
        lerobot_eval, "trange", lambda *args, **kwargs: stock(*args, **{**kwargs, "disable": True})
    )


class BatchedEvaluator:
    """Runs a policy from given initial states, `batch_size` episodes at a time per task.

    Two ways to run a batch, with the same results:
    - chunked (ACT without temporal ensembling, the default policy): the policy is asked for an action chunk
      only when it would ask itself (`predict_action_chunk` every `n_action_steps` steps, as ACT's own
      `select_action` does), observations are preprocessed only then, and the chunk is postprocessed at once
      (elementwise: the same numbers). That skips LeRobot's per-step pipeline work, which otherwise costs as
      much as a quarter of an evaluation on a CPU;
    - LeRobot's own `rollout()` for every other policy (Diffusion keeps observation history per step).
    `tests/test_eval.py` checks both give the same episodes.
    """

    def __init__(
        self, suite: TaskSuite, loaded: LoadedPolicy, batch_size: int = 10, chunked: bool | None = None
    ):
        if batch_size < 1:
            raise AdaDemoError(f"--eval.batch_size must be >= 1, got {batch_size}")
        self.suite, self.loaded, self.batch_size = suite, loaded, batch_size
        cfg = loaded.config
        can_chunk = cfg.type == "act" and getattr(cfg, "temporal_ensemble_coeff", None) is None
        self.chunked = can_chunk if chunked is None else chunked and can_chunk
        self._pools: dict[str, EnvPool] = {}  # per task: the envs batches are made of, reused across batches
        self.env_steps = 0

    def _envs(self, task: str, n: int) -> list:
        pool = cached_for_task(self._pools, task, lambda: EnvPool(self.suite, task), keep=1)
        return pool.take(n)

    def run(self, task: str, seeds: list[int]) -> list[EpisodeRecord]:
        """One episode per seed, from that seed's initial state, in `batch_size` batches; records in seed order.

        Every random draw of an episode comes from its seed: a policy that samples (Diffusion) gets each
        episode's noise from that episode's seed, and torch's global generator is seeded from the batch's seeds,
        so an outcome depends neither on the worker nor on what ran before. Inference runs on one torch thread:
        the float sums of a matrix product depend on the thread count, and episodes amplify such differences, so
        outcomes would otherwise depend on the machine's and the worker's thread settings (batches of <= 10
        observations gain little from more threads)."""
        return [record for record, _ in self._run(task, seeds, traced=False)]

    def run_traced(
        self, task: str, seeds: list[int], with_states: bool = True
    ) -> list[tuple[EpisodeRecord, RolloutTrace]]:
        """`run`, also keeping every episode's observations and actions (and whole states, with `with_states`)
        step by step (the same episodes: tracing only reads the simulator)."""
        return self._run(task, seeds, traced=True, with_states=with_states)

    def _run(
        self, task: str, seeds: list[int], traced: bool, with_states: bool = True
    ) -> list[tuple[EpisodeRecord, RolloutTrace | None]]:
        import torch

        out: list[tuple[EpisodeRecord, RolloutTrace | None]] = []
        for begin in range(0, len(seeds), self.batch_size):
            batch_seeds = seeds[begin : begin + self.batch_size]
            states = [self.suite.sample_initial_state(task, s) for s in batch_seeds]
            envs = self._envs(task, len(batch_seeds))
            if traced:
                envs = [RolloutTracer(env, with_states) for env in envs]
            torch.manual_seed(derive_seed("rollout", *batch_seeds) % 2**63)
            with torch.inference_mode(), one_torch_thread():
                run_batch = self._run_chunked if self.chunked else self._run_lerobot_rollout
                results = run_batch(task, envs, states, batch_seeds)
            for i, (s, st, (success, steps, reward)) in enumerate(
                zip(batch_seeds, states, results, strict=True)
            ):
                self.env_steps += steps
                record = EpisodeRecord(
                    task, int(s), np.asarray(st, np.float64).tolist(), success, steps, reward
                )
                out.append((record, envs[i].trace if traced else None))
        return out

    def _run_chunked(
        self, task: str, envs: list, states: list, seeds: list[int]
    ) -> list[tuple[bool, int, float]]:
        from lerobot.envs.utils import preprocess_observation

        loaded, n_action_steps = self.loaded, self.loaded.config.n_action_steps
        description = self.suite.task_description(task)
        observations = [
            env.reset(options={"initial_state": s})[0] for env, s in zip(envs, states, strict=True)
        ]
        loaded.policy.reset()
        done, success = [False] * len(envs), [False] * len(envs)
        steps, rewards = [0] * len(envs), [[] for _ in envs]
        max_steps, t = self.suite.config.max_episode_steps, 0
        while not all(done) and t < max_steps:
            if t % n_action_steps == 0:
                batch = preprocess_observation(
                    {
                        key: np.stack([o[key] for o in observations])
                        for key in ("agent_pos", "environment_state")
                    }
                    | _stacked_pixels(observations)
                )
                batch["task"] = [description] * len(envs)
                chunk = loaded.policy.predict_action_chunk(loaded.preprocessor(batch))[:, :n_action_steps]
                chunk = loaded.postprocessor(chunk).to("cpu").numpy()
            for i, env in enumerate(envs):
                if done[i]:
                    continue  # a finished episode's row keeps its final observation, as in LeRobot's rollout
                observations[i], r, terminated, truncated, info = env.step(chunk[i, t % n_action_steps])
                steps[i] += 1
                rewards[i].append(r)
                if terminated or truncated:
                    done[i], success[i] = True, bool(info["is_success"])
            t += 1
        returns = [float(np.asarray(r, dtype=np.float64).sum()) for r in rewards]  # summed as rollout() sums
        return list(zip(success, steps, returns, strict=True))

    def _run_lerobot_rollout(
        self, task: str, envs: list, states: list, seeds: list[int]
    ) -> list[tuple[bool, int, float]]:
        import gymnasium as gym
        from lerobot.processor import PolicyProcessorPipeline
        from lerobot.scripts.lerobot_eval import rollout

        vector = gym.vector.SyncVectorEnv([lambda env=env: env for env in envs])
        vector.set_attr("hold_after_episode", True)  # no simulation after an episode ends
        vector.set_attr("pending_initial_state", [np.asarray(s, dtype=np.float64) for s in states])
        identity = PolicyProcessorPipeline(steps=[])
        with _without_rollout_progress_bar(), _noise_per_episode(self.loaded, seeds):
            out = rollout(
                vector,
                self.loaded.policy,
                identity,
                identity,
                self.loaded.preprocessor,
                self.loaded.postprocessor,
            )
        vector.set_attr("hold_after_episode", False)
        done, success, reward = out["done"].numpy(), out["success"].numpy(), out["reward"].numpy()
        results = []
        for i in range(len(envs)):
            steps = int(np.argmax(done[i]) + 1) if done[i].any() else done.shape[1]
            results.append((bool(success[i, :steps].any()), steps, float(reward[i, :steps].sum())))
        return results

    def close(self) -> None:
        for pool in self._pools.values():
            pool.close()
        self._pools.clear()


def _stacked_pixels(observations: list[dict]) -> dict:
    if "pixels" not in observations[0]:
        return {}
    return {
        "pixels": {
            cam: np.stack([o["pixels"][cam] for o in observations]) for cam in observations[0]["pixels"]
        }
    }


class EnvPool:
    """One task's envs for batched evaluation: grown to the largest batch asked for, each env reused."""

    def __init__(self, suite: TaskSuite, task: str):
        self.suite, self.task, self.envs = suite, task, []

    def take(self, n: int) -> list:
        while len(self.envs) < n:
            self.envs.append(self.suite.make_env(self.task, terminate_on_success=True))
        return self.envs[:n]

    def close(self) -> None:
        for env in self.envs:
            env.close()


@contextlib.contextmanager
def one_torch_thread():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _noise_per_episode(loaded: LoadedPolicy, episode_seeds: list[int]):
    """For a policy that samples its actions (Diffusion), each episode's noise from its own seed: the row of the
    batch gets `randn` from a generator seeded by the episode, drawn every step, so the noise of an episode's
    k-th chunk does not depend on the batch it runs in. Other policies are left as they are."""
    import torch

    if getattr(loaded.config, "type", None) != "diffusion":
        return contextlib.nullcontext()
    policy, cfg = loaded.policy, loaded.config
    shape = (cfg.horizon, cfg.action_feature.shape[0])
    generators = [
        torch.Generator().manual_seed(derive_seed(s, "policy-noise") % 2**63) for s in episode_seeds
    ]
    stock = policy.select_action

    def select_action(batch, noise=None):
        noise = torch.stack([torch.randn(shape, generator=g) for g in generators]).to(cfg.device)
        return stock(batch, noise=noise)

    return temporarily_set(policy, "select_action", select_action)


def success_table(records: list[EpisodeRecord], tasks: list[str]) -> pd.DataFrame:
    df = pd.DataFrame([record_row(r) for r in records])
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
    from adademo_lerobot.core.files import atomic_write_text

    output_dir.mkdir(parents=True, exist_ok=True)
    tmp = output_dir / ".eval_episodes.parquet.tmp"
    pd.DataFrame([record_row(r) for r in records]).to_parquet(tmp)
    tmp.replace(output_dir / "eval_episodes.parquet")
    summary = {**meta, "per_task": success.to_dict(orient="records")}
    atomic_write_text(output_dir / "eval_summary.json", json.dumps(summary, indent=2))
