"""`--collector.type=planner`: an expert that plans with the simulator (predictive sampling with MPPI weights).

At every step it samples `samples` action sequences around its current plan (Gaussian noise of std `noise`; the
plan itself is one of them), rolls each out for `horizon` steps from the current state, restored exactly in a
second copy of the task's env, and scores it by the task's own reward summed over the rollout. The plan moves to
the reward-weighted mean of the samples, with weights exp((R - max R) / (temperature x std R)) (MPPI; `iterations`
times per step), the first action is executed and the plan shifts by one step.

It needs only what every suite here with full-state restore has (MetaWorld, Fetch, Adroit): a state to restore
at any step and a reward (dense rewards plan best: Fetch's is sparse). It acts from any state, so it also takes
over failed rollouts (`--demo_start=takeover`). Its random draws come from the state it plans from, so the same
state gives the same action wherever it runs (Ray == local).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from adademo_lerobot.collectors.base import CollectorConfig, SimulatedExpertCollector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import TaskSuite, cached_for_task


@CollectorConfig.register_subclass("planner")
@dataclass
class PlannerCollectorConfig(CollectorConfig):
    """A sampling-based model-predictive controller that plans with the suite's simulator (any suite that restores
    any state: MetaWorld, Fetch, Adroit)."""

    expert_hint = "plans with the simulator; any suite with full-state restore"

    # Action sequences sampled around the plan at every step (one of them is the plan itself).
    samples: int = 32
    # Steps each sampled sequence is rolled out for (its reward is summed over them).
    horizon: int = 12
    # Sample-and-reweight passes per executed step.
    iterations: int = 1
    # Std of the Gaussian noise around the plan, in the [-1, 1] action box.
    noise: float = 0.3
    # MPPI temperature, relative to the spread (std) of the sampled returns: small picks the best sample.
    temperature: float = 0.1

    def check_fields(self) -> None:
        for name in ("samples", "horizon", "iterations"):
            if getattr(self, name) < 1:
                raise AdaDemoError(f"--collector.{name} must be >= 1, got {getattr(self, name)}")
        if not self.noise > 0:
            raise AdaDemoError(f"--collector.noise must be > 0, got {self.noise}")
        if not self.temperature > 0:
            raise AdaDemoError(f"--collector.temperature must be > 0, got {self.temperature}")

    def build(self, suite: TaskSuite) -> PlannerExpert:
        return PlannerExpert(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        return f"{suite.name}-planner"

    def expert_class(self, suite: TaskSuite) -> type:
        return PlannerExpert


class PlannerExpert(SimulatedExpertCollector):
    acts_mid_episode = True

    def __init__(self, suite: TaskSuite, config: PlannerCollectorConfig):
        config.check_fields()
        if not suite.restores_any_state:
            raise AdaDemoError(
                f"--collector.type=planner plans by restoring the simulator's state at every step; suite "
                f"{suite.name!r} restores initial states only: use --collector.type=scripted, callable or policy"
            )
        super().__init__(suite, config)
        self.name = f"{suite.name}-planner"
        self._planning_envs: dict = {}

    def _planning_env(self, task: str):
        return cached_for_task(
            self._planning_envs, task, lambda: self.suite.make_env(task, terminate_on_success=False), keep=4
        )

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        acting = self._env(task).unwrapped
        return self._acting_from(task, lambda: acting.get_state())

    def expert_first_action(self, task: str) -> Callable[[dict, np.ndarray], np.ndarray]:
        return lambda observation, state: self.plan(task, np.asarray(state, np.float64), self._empty_plan())[
            0
        ]

    def _acting_from(
        self, task: str, current_state: Callable[[], np.ndarray]
    ) -> Callable[[dict], np.ndarray]:
        plan = self._empty_plan()

        def act(observation: dict) -> np.ndarray:
            nonlocal plan
            plan = self.plan(task, current_state(), plan)
            action = plan[0].copy()
            plan = np.concatenate([plan[1:], plan[-1:]])  # receding horizon: the rest of the plan, shifted
            return action

        return act

    def _empty_plan(self) -> np.ndarray:
        return np.zeros((self.config.horizon, self.suite.action_dim))

    def plan(self, task: str, state: np.ndarray, plan: np.ndarray) -> np.ndarray:
        """`plan` improved from `state`: the reward-weighted mean of sequences sampled around it."""
        cfg: PlannerCollectorConfig = self.config
        env = self._planning_env(task)
        env.reset(options={"state": state})
        start = env.snapshot()
        rng = np.random.default_rng(zlib.crc32(np.ascontiguousarray(state).tobytes()))
        for _ in range(cfg.iterations):
            noise = rng.normal(0.0, cfg.noise, (cfg.samples, *plan.shape))
            noise[0] = 0.0
            candidates = np.clip(plan + noise, -1.0, 1.0)
            returns = np.empty(cfg.samples)
            for k, actions in enumerate(candidates):
                env.rewind(start)
                returns[k] = sum(env.step(a)[1] for a in actions)
            spread = returns.std()
            if spread == 0:
                continue  # no sample is better than another: keep the plan
            weights = np.exp((returns - returns.max()) / (cfg.temperature * spread))
            plan = np.tensordot(weights / weights.sum(), candidates, axes=1)
        return plan

    def close(self) -> None:
        super().close()
        for env in self._planning_envs.values():
            env.close()
        self._planning_envs.clear()
