"""`--strategy.type=task_only`, ablation A: as many demonstrations per task as AdaDemo would allocate, but from
fresh random initial states.

Without a budget the allocation is the paper's estimate N_k = E / SR_k - E (capped at CAP), with SR_k measured on
`plan_episodes_per_task` evaluation episodes of this round's policy. With `--strategy.budget=B` it is the
budgeted strategy's loop (the same evaluations, posterior and split of exactly B demonstrations) with every
failure answered from a fresh state instead of the failed one: budgeted minus this is principle B alone.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import plan_state_seeds
from adademo_lerobot.strategies.adademo import check_decay, check_eval_bound
from adademo_lerobot.strategies.base import (
    DEFAULT_TARGET_SUCCESSES,
    PerRound,
    StrategyConfig,
    check_per_round,
    per_round,
    planned_demos,
)
from adademo_lerobot.strategies.budgeted import BudgetedConfig, BudgetedStrategy
from adademo_lerobot.strategies.estimates import DEFAULT_DECAY
from adademo_lerobot.strategies.round_context import RoundContext


def estimate_success(ctx: RoundContext, task: str, record: TaskRoundRecord, episodes: int) -> float:
    """SR_k on the round's plan states (journaled like every evaluation); fills the record's counts."""
    outcomes = ctx.evaluate(task, plan_state_seeds(ctx.seed, ctx.round_index, task, episodes))
    record.eval_episodes = len(outcomes)
    record.successes = sum(o.success for o in outcomes)
    record.failures = record.eval_episodes - record.successes
    return record.successes / record.eval_episodes


DEFAULT_PLAN_EPISODES = 20  # evaluation episodes per task that measure SR_k (without a budget)


@StrategyConfig.register_subclass("task_only")
@dataclass
class TaskOnlyConfig(StrategyConfig):
    """Ablation A: AdaDemo's demos per task (N_k = E / SR_k - E, capped), from fresh initial states."""

    description = "ablation A: AdaDemo's demos per task (N = E/SR - E) from fresh initial states"
    needs_policy = True
    collects_at_failed_states = False

    # E_i in N_k = E / SR_k - E (default 10); or leave it out and give a budget.
    target_successes: PerRound = per_round()
    # CAP_i: at most this many new demonstrations per task per round.
    max_demos_per_task: PerRound = per_round(50)
    # Evaluation episodes per task that estimate SR_k (without a budget).
    plan_episodes_per_task: int = DEFAULT_PLAN_EPISODES
    # B_i: demonstrations per round, split as the budgeted strategy splits them (from fresh states).
    budget: PerRound = per_round()
    # With a budget: the budgeted strategy's bound on evaluation episodes per task and round, and its decay.
    max_eval_episodes_per_task: int | None = None
    posterior_decay: float = DEFAULT_DECAY

    def validate(self) -> None:
        check_per_round("target_successes", self.target_successes)
        check_per_round("budget", self.budget)
        check_per_round("max_demos_per_task", self.max_demos_per_task, required=True)
        check_per_round("plan_episodes_per_task", PerRound([self.plan_episodes_per_task]))
        check_eval_bound(self.max_eval_episodes_per_task)
        check_decay(self.posterior_decay)
        if self.budget and self.target_successes:
            raise AdaDemoError(
                f"--strategy.budget={list(self.budget)} and --strategy.target_successes="
                f"{list(self.target_successes)} both set the round's size: pass one"
            )
        if self.budget and self.plan_episodes_per_task != DEFAULT_PLAN_EPISODES:
            raise AdaDemoError(
                "--strategy.plan_episodes_per_task sets the evaluations without a budget; with --strategy.budget "
                "the budgeted loop evaluates (bounded by --strategy.max_eval_episodes_per_task): drop one"
            )
        if not self.budget and self.max_eval_episodes_per_task is not None:
            raise AdaDemoError(
                "--strategy.max_eval_episodes_per_task bounds the budgeted loop: give --strategy.budget too "
                "(without a budget, --strategy.plan_episodes_per_task sets the evaluations)"
            )

    def can_plan(self) -> bool:
        return not self.budget  # with a budget its round is the budgeted strategy's loop

    def build(self, round_in_run: int) -> TaskOnlyStrategy | BudgetedStrategy:
        cap = self.max_demos_per_task.at(round_in_run)
        if self.budget:  # the budgeted strategy's round, each failure answered from a fresh state
            budgeted = BudgetedConfig(
                self.budget, self.max_demos_per_task, self.max_eval_episodes_per_task, self.posterior_decay
            )
            return dataclasses.replace(budgeted.build(round_in_run), at_failed_states=False, name="task_only")
        return TaskOnlyStrategy(
            self.target_successes.at(round_in_run) or DEFAULT_TARGET_SUCCESSES,
            cap,
            self.plan_episodes_per_task,
        )


@dataclass
class TaskOnlyStrategy:
    target_successes: int
    cap: int
    plan_episodes_per_task: int
    name = "task_only"
    commits_by_task = True

    def task_cap(self, task: str) -> int:
        return self.cap

    def start(self, ctx: RoundContext, resumed: dict | None) -> dict:
        return {
            "target_successes": self.target_successes,
            "max_demos_per_task": self.cap,
            "plan_episodes_per_task": self.plan_episodes_per_task,
        }

    def expand(self, ctx: RoundContext) -> list[TaskRoundRecord]:
        def one_task(task: str) -> TaskRoundRecord:
            record = ctx.new_record(task, self.name, self.target_successes, self.cap)
            sr = estimate_success(ctx, task, record, self.plan_episodes_per_task)
            record.planned_demos = planned_demos(self.target_successes, sr, self.cap)
            ctx.collect_from_fresh_states(task, record.planned_demos, record)
            record.cap_hit = record.planned_demos >= self.cap
            return record

        return ctx.run_tasks(one_task)
