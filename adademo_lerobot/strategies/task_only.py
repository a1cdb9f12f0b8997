"""`--strategy.type=task_only`, ablation A: as many demonstrations per task as AdaDemo would allocate, but from
fresh random initial states.

The allocation is the paper's estimate N_k = E / SR_k - E (capped at CAP), with SR_k measured on
`plan_episodes_per_task` evaluation episodes of this round's policy.
"""

from __future__ import annotations

from dataclasses import dataclass

from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.seeds import plan_state_seeds
from adademo_lerobot.strategies.base import (
    DEFAULT_TARGET_SUCCESSES,
    PerRound,
    RoundContext,
    StrategyConfig,
    check_per_round,
    per_round,
    planned_demos,
)


def estimate_success(ctx: RoundContext, task: str, record: TaskRoundRecord, episodes: int) -> float:
    """SR_k on the round's plan states (journaled like every evaluation); fills the record's counts."""
    outcomes = ctx.evaluate(task, plan_state_seeds(ctx.seed, ctx.round_index, task, episodes))
    record.eval_episodes = len(outcomes)
    record.successes = sum(o.success for o in outcomes)
    record.failures = record.eval_episodes - record.successes
    return record.successes / record.eval_episodes


@StrategyConfig.register_subclass("task_only")
@dataclass
class TaskOnlyConfig(StrategyConfig):
    """Ablation A: AdaDemo's demos per task (N_k = E / SR_k - E, capped), from fresh initial states."""

    description = "ablation A: AdaDemo's demos per task (N = E/SR - E) from fresh initial states"
    needs_policy = True
    collects_at_failed_states = False

    # E_i in N_k = E / SR_k - E.
    target_successes: PerRound = per_round(DEFAULT_TARGET_SUCCESSES)
    # CAP_i: at most this many new demonstrations per task per round.
    max_demos_per_task: PerRound = per_round(50)
    # Evaluation episodes per task that estimate SR_k.
    plan_episodes_per_task: int = 20

    def validate(self) -> None:
        check_per_round("target_successes", self.target_successes, required=True)
        check_per_round("max_demos_per_task", self.max_demos_per_task, required=True)
        check_per_round("plan_episodes_per_task", PerRound([self.plan_episodes_per_task]))

    def build(self, round_in_run: int) -> TaskOnlyStrategy:
        return TaskOnlyStrategy(
            self.target_successes.at(round_in_run),
            self.max_demos_per_task.at(round_in_run),
            self.plan_episodes_per_task,
        )


@dataclass
class TaskOnlyStrategy:
    target_successes: int
    cap: int
    plan_episodes_per_task: int
    name = "task_only"
    commits_by_task = True

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
