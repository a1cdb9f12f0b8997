"""`--collector.type=planner`: an expert that plans with the simulator (predictive sampling with MPPI weights).

At every step it samples `samples` action sequences around its current plan (Gaussian noise of std `noise`, drawn
every `knot_steps` steps and interpolated linearly in between, so a sequence moves smoothly; the plan itself is
one of them), rolls each out for `horizon` steps from the current state, restored exactly in a second copy of the
task's env, and scores it by the task's reward summed over the rollout. Where the task env offers rollouts in C
(`batched_rollouts`: Adroit) they run there, scored by the task's planning reward (`reward=planning`, see
suites/adroit_rewards.py) or its own (`reward=env`); elsewhere through the env's own step and reward. The plan
moves to the reward-weighted mean of the samples, with weights exp((R - max R) / (temperature x std R)) (MPPI;
`iterations` times per step), the first action is executed and the plan shifts by one step.

It needs only what every suite here with full-state restore has (MetaWorld, Fetch, Adroit): a state to restore
at any step and a reward (dense rewards plan best: Fetch's is sparse). It acts from any state, so it also takes
over failed rollouts (`--demo_start=takeover`). Its random draws come from the state it plans from, so the same
state gives the same action wherever it runs (Ray == local); with `common_noise` they come from the attempt's step,
the same for every episode, which makes demonstrations from nearby starts agree (for imitation). With
`scripted_first` it is the fallback of the suite's scripted expert: the planner makes one attempt where the
scripted attempts failed (on MetaWorld, from the takeover states a failing policy leaves, where the scripted
controllers, written for starts, often fail).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from adademo_lerobot.collectors.base import CollectorConfig, SimulatedExpertCollector
from adademo_lerobot.collectors.scripted import SCRIPTED_EXPERTS
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.base import TaskSuite, cached_for_task, split_task_list


@dataclass
class PlannerTaskSettings:
    """One task's own values of the planner's search fields (None: the collector's); the other fields are the
    collector's for every task."""

    samples: int | None = None
    horizon: int | None = None
    knot_steps: int | None = None
    iterations: int | None = None
    noise: float | None = None
    temperature: float | None = None
    common_noise: bool | None = None
    plan_decay: float | None = None


@CollectorConfig.register_subclass("planner")
@dataclass
class PlannerCollectorConfig(CollectorConfig):
    """A sampling-based model-predictive controller that plans with the suite's simulator (any suite that restores
    any state: MetaWorld, Fetch, Adroit)."""

    expert_hint = "plans with the simulator; any suite with full-state restore"

    @classmethod
    def serves(cls, suite: TaskSuite) -> bool:
        return suite.restores_any_state

    # Action sequences sampled around the plan at every step (one of them is the plan itself).
    samples: int = 32
    # Steps each sampled sequence is rolled out for (its reward is summed over them).
    horizon: int = 16
    # Steps between the noise's knots (linear in between); 1 = independent noise at every step.
    knot_steps: int = 4
    # Sample-and-reweight passes per executed step.
    iterations: int = 1
    # Std of the Gaussian noise around the plan, in the [-1, 1] action box.
    noise: float = 0.3
    # MPPI temperature, relative to the spread (std) of the sampled returns: small picks the best sample.
    temperature: float = 0.1
    # Every episode draws the same noise at the same step (common random numbers), instead of noise drawn from the
    # state: nearby starts then pick alike samples, so the demonstrations agree more with each other and a policy
    # can imitate them (Adroit hammer, benchmarks/results/adroit.md). Still one action per state and step.
    common_noise: bool = False
    # Share of the plan pulled back to the neutral action (0) before each step's search, in [0, 1): bounds how far
    # the dimensions the reward barely scores (a hand's fingers) wander from one demonstration to the next.
    plan_decay: float = 0.0
    # `planning`: the suite's planning reward where it has one (Adroit), else the env's; `env`: the env's own.
    reward: str = "planning"
    # Threads for rollouts in C (Adroit); 1 keeps a planner to one core (Ray workers run one each).
    threads: int = 1
    # Tasks the suite's scripted expert demonstrates alone, comma-separated (Adroit: door,relocate, where it
    # does better than the planner); the others are planned (or, with scripted_first, get the planner after it).
    scripted_tasks: str | None = None
    # The suite's scripted expert makes each demonstration's attempts first; where they all fail, the planner
    # makes one attempt more from the same start, a takeover state included (MetaWorld's corrections).
    scripted_first: bool = False
    # Search fields set per task, by task name: in a recipe `task_settings: {hammer: {common_noise: true}}`, on
    # the command line `--collector.task_settings='{"hammer": {"common_noise": true}}'`; the tasks not named plan
    # with the fields above (Adroit: hammer's demonstrations need common noise to be imitable, pen's cost three
    # times as much with it and stay unimitable: benchmarks/results/adroit.md).
    task_settings: dict[str, PlannerTaskSettings] = field(default_factory=dict)
    # Threads change the speed only: every rollout in C is independent, and so is the draw that scores it.
    execution_fields: ClassVar[tuple[str, ...]] = ("threads",)

    def check_fields(self) -> None:
        for name in ("samples", "horizon", "iterations", "knot_steps", "threads"):
            if getattr(self, name) < 1:
                raise AdaDemoError(f"--collector.{name} must be >= 1, got {getattr(self, name)}")
        if not self.noise > 0:
            raise AdaDemoError(f"--collector.noise must be > 0, got {self.noise}")
        if not self.temperature > 0:
            raise AdaDemoError(f"--collector.temperature must be > 0, got {self.temperature}")
        if not 0 <= self.plan_decay < 1:
            raise AdaDemoError(f"--collector.plan_decay must be in [0, 1), got {self.plan_decay}")
        if self.reward not in ("planning", "env"):
            raise AdaDemoError(f"--collector.reward must be planning or env, got {self.reward!r}")
        for task in self.task_settings:
            try:
                self.for_task(task).check_fields()
            except AdaDemoError as error:
                raise AdaDemoError(f"--collector.task_settings of {task}: {error}") from None

    def for_task(self, task: str) -> PlannerCollectorConfig:
        """The config a task plans with: the collector's, with that task's `task_settings` over it."""
        own = self.task_settings.get(task)
        if own is None:
            return self
        changed = {
            f.name: getattr(own, f.name) for f in dataclasses.fields(own) if getattr(own, f.name) is not None
        }
        return dataclasses.replace(self, task_settings={}, **changed)

    def build(self, suite: TaskSuite) -> PlannerExpert:
        return PlannerExpert(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        if self.scripted_first:
            alone = f"+scripted-only:{self.scripted_tasks}" if self.scripted_tasks else ""
            return f"{suite.name}-scripted+planner{alone}"
        return f"{suite.name}-planner" + (f"+scripted:{self.scripted_tasks}" if self.scripted_tasks else "")

    def expert_class(self, suite: TaskSuite) -> type:
        return PlannerExpert

    def scripted_flag(self) -> str | None:
        """The flag that brings in the suite's scripted expert, as an error names it (None: neither is set)."""
        if self.scripted_first:
            return "scripted_first=true"
        return f"scripted_tasks={self.scripted_tasks}" if self.scripted_tasks else None

    def check_acts_mid_episode(self, suite: TaskSuite) -> None:
        scripted = SCRIPTED_EXPERTS.get(suite.name)
        flag = self.scripted_flag()
        if flag and scripted is not None and not scripted.acts_mid_episode:
            raise AdaDemoError(
                f"--demo_start=takeover: the scripted expert of --collector.{flag} acts only from an episode's "
                "start; leave --collector.scripted_tasks empty and scripted_first false to plan every task"
            )


class PlannerExpert(SimulatedExpertCollector):
    acts_mid_episode = True

    def __init__(self, suite: TaskSuite, config: PlannerCollectorConfig):
        config.check_fields()
        if not config.serves(suite):
            others = (
                "scripted, callable or policy" if suite.name in SCRIPTED_EXPERTS else "callable or policy"
            )
            raise AdaDemoError(
                f"--collector.type=planner plans by restoring the simulator's state at every step; suite "
                f"{suite.name!r} restores initial states only: use --collector.type={others}"
            )
        super().__init__(suite, config)
        self.name = config.expert_name(suite)
        self._planning_envs: dict = {}
        alone = self._scripted_task_names(suite, config)
        self._scripted_alone = set(alone)
        self._scripted = self._scripted_expert(suite, config, alone)
        self._planning_after_scripted = False  # scripted_first: set while the planner makes its one attempt
        self._task_configs = self._configs_by_task(suite, config)

    @staticmethod
    def _configs_by_task(
        suite: TaskSuite, config: PlannerCollectorConfig
    ) -> dict[str, PlannerCollectorConfig]:
        """Each task's config: the collector's, or that of the `task_settings` entry naming it."""
        configs = dict.fromkeys(suite.tasks, config)
        for name in config.task_settings:
            for task in run_task_names(suite, "task_settings", [name]):
                configs[task] = config.for_task(name)
        return configs

    @staticmethod
    def _scripted_task_names(suite: TaskSuite, config: PlannerCollectorConfig) -> list[str]:
        return run_task_names(suite, "scripted_tasks", split_task_list(config.scripted_tasks or ""))

    @staticmethod
    def _scripted_expert(
        suite: TaskSuite, config: PlannerCollectorConfig, alone: list[str]
    ) -> SimulatedExpertCollector | None:
        """The suite's scripted expert for the tasks it demonstrates `alone` (every task with `scripted_first`;
        None if neither is set), refused in one line if it has none for them."""
        flag = config.scripted_flag()
        if flag is None:
            return None
        names = list(suite.tasks) if config.scripted_first else alone
        if suite.name not in SCRIPTED_EXPERTS:
            raise AdaDemoError(f"--collector.{flag}: suite {suite.name!r} has no scripted expert")
        # Built for a suite of those tasks only (it refuses one with a task it has no controller for); its
        # controllers read the observation at fixed indices, so they act on this suite's envs as they are.
        only = make_suite(dataclasses.replace(suite.config, tasks=",".join(names)))
        try:
            return SCRIPTED_EXPERTS[suite.name](only, config)
        except AdaDemoError as error:
            refusal = str(error).split(";")[0]  # its advice (use the planner) does not apply here
            advice = (
                "it needs the scripted expert of every task"
                if config.scripted_first
                else "leave those tasks out to plan them"
            )
            raise AdaDemoError(f"--collector.{flag}: {refusal}; {advice}") from None

    def _planning_env(self, task: str):
        return cached_for_task(
            self._planning_envs, task, lambda: self.suite.make_env(task, terminate_on_success=False), keep=4
        )

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        scripted = self._scripted is not None and task in self._scripted.suite.tasks
        if scripted and not self._planning_after_scripted:
            return self._scripted.expert_for(task)
        acting = self._env(task).unwrapped
        return self._acting_from(task, acting)

    def _attempts(self, env, task: str, result, start: dict, n: int, correction_from) -> bool:
        """With `scripted_first`: the scripted expert's n attempts, then, where they all fail, one planned attempt
        (counted as one attempt more; not on `scripted_tasks`, which the scripted expert demonstrates alone)."""
        found = super()._attempts(env, task, result, start, n, correction_from)
        if found or not self.config.scripted_first or task in self._scripted_alone:
            return found
        self._planning_after_scripted = True
        try:
            return super()._attempts(env, task, result, start, 1, correction_from)
        finally:
            self._planning_after_scripted = False

    def expert_first_action(self, task: str) -> Callable[[dict, np.ndarray], np.ndarray]:
        if self.config.scripted_first:  # the disagreement rule asks the expert that acts first
            return self._scripted.expert_first_action(task)
        return lambda observation, state: self.plan(
            task, np.asarray(state, np.float64), self._empty_plan(task)
        )[0]

    def _acting_from(self, task: str, acting) -> Callable[[dict], np.ndarray]:
        plan = self._empty_plan(task)
        step = 0

        def act(observation: dict) -> np.ndarray:
            nonlocal plan, step
            plan = self.plan(task, acting.get_state(), plan, acting, step=step)
            step += 1
            action = plan[0].copy()
            plan = np.concatenate([plan[1:], plan[-1:]])  # receding horizon: the rest of the plan, shifted
            return action

        return act

    def _empty_plan(self, task: str) -> np.ndarray:
        return np.zeros((self._task_configs[task].horizon, self.suite.action_dim))

    def plan(self, task: str, state: np.ndarray, plan: np.ndarray, acting=None, step: int = 0) -> np.ndarray:
        """`plan` improved from `state`, the attempt's `step`-th: the reward-weighted mean of sequences sampled
        around it. Given the env `acting` in that state, rollouts in C start from it directly (they leave it as it
        is, and start from its exact state, the solver's warm start included, which a restore resets)."""
        cfg = self._task_configs[task]
        if acting is not None and hasattr(acting, "batched_rollouts"):
            env = acting
        else:
            env = self._planning_env(task)
            env.reset(options={"state": state})
        returns_of = self._returns_from_here(env)
        used = getattr(env, "used_action_dims", None)  # dims the task ignores stay at the plan's (zero)
        rng = noise_generator(state, step, cfg.common_noise)
        if cfg.plan_decay:
            plan = plan * (1.0 - cfg.plan_decay)
        for _ in range(cfg.iterations):
            noise = smooth_noise(rng, cfg.samples, cfg.horizon, plan.shape[1], cfg.knot_steps, cfg.noise)
            noise[0] = 0.0
            if used is not None:
                noise[..., np.setdiff1d(np.arange(plan.shape[1]), used)] = 0.0
            candidates = np.clip(plan + noise, -1.0, 1.0)
            returns = returns_of(candidates)
            spread = returns.std()
            if spread == 0:
                continue  # no sample is better than another: keep the plan
            weights = np.exp((returns - returns.max()) / (cfg.temperature * spread))
            plan = np.tensordot(weights / weights.sum(), candidates, axes=1)
        return plan

    def _returns_from_here(self, env) -> Callable[[np.ndarray], np.ndarray]:
        """Summed rewards of candidate sequences from `env`'s current state: in C where the env can, else by
        stepping and rewinding the env itself."""
        cfg: PlannerCollectorConfig = self.config
        if hasattr(env, "batched_rollouts"):
            rollouts = env.batched_rollouts(shaped=cfg.reward == "planning", threads=cfg.threads)
            return lambda candidates: rollouts.rewards(candidates).sum(axis=1)
        start = env.snapshot()

        def stepped(candidates: np.ndarray) -> np.ndarray:
            returns = np.empty(len(candidates))
            for k, actions in enumerate(candidates):
                env.rewind(start)
                returns[k] = sum(env.step(a)[1] for a in actions)
            return returns

        return stepped

    def close(self) -> None:
        super().close()
        if self._scripted is not None:
            self._scripted.close()
        for env in self._planning_envs.values():
            env.close()
        self._planning_envs.clear()


def run_task_names(suite: TaskSuite, flag: str, names: list[str]) -> list[str]:
    """`--collector.<flag>`'s task names as the suite's task ids, refused in one line if not among its tasks."""
    tasks = suite.canonical_task_names(names)
    unknown = [t for t in tasks if t not in suite.tasks]
    if unknown:
        raise AdaDemoError(
            f"--collector.{flag}: {', '.join(unknown)} not among this run's tasks ({', '.join(suite.tasks)})"
        )
    return tasks


def noise_generator(state: np.ndarray, step: int, common: bool) -> np.random.Generator:
    """The planning noise's random draws at one step: from the state planned from (the same state, the same
    draws, wherever it runs), or with `common` from the step of the attempt alone (every episode alike)."""
    return np.random.default_rng(step if common else zlib.crc32(np.ascontiguousarray(state).tobytes()))


def smooth_noise(
    rng: np.random.Generator, samples: int, horizon: int, dim: int, knot_steps: int, std: float
) -> np.ndarray:
    """(samples, horizon, dim) Gaussian noise of std `std` at knots `knot_steps` apart, linear in between."""
    knots = rng.normal(0.0, std, (samples, (horizon - 1) // knot_steps + 2, dim))
    position = np.arange(horizon) / knot_steps
    left = np.floor(position).astype(int)
    fraction = (position - left)[None, :, None]
    return knots[:, left] * (1 - fraction) + knots[:, left + 1] * fraction
