"""`--strategy.type=uniform`: the paper's Uniform baseline, N new demonstrations per task from fresh random initial
states, no evaluation."""

from __future__ import annotations

from dataclasses import dataclass

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.strategies.base import (
    PerRound,
    StrategyConfig,
    check_per_round,
    per_round,
    split_evenly,
)
from adademo_lerobot.strategies.round_context import RoundContext


@StrategyConfig.register_subclass("uniform")
@dataclass
class UniformConfig(StrategyConfig):
    """The paper's baseline: N new demonstrations per task from fresh initial states (or a budget split evenly)."""

    description = "Uniform (the paper's baseline): N demos per task from fresh initial states"
    needs_policy = False
    collects_at_failed_states = False

    # N_i: new demonstrations per task per round (default 10); or leave it out and give a budget.
    demos_per_task: PerRound = per_round()
    # B_i: demonstrations per round, split evenly over the tasks (the first B mod K tasks get one more).
    budget: PerRound = per_round()

    def validate(self) -> None:
        check_per_round("demos_per_task", self.demos_per_task)
        check_per_round("budget", self.budget)
        if self.budget and self.demos_per_task:
            raise AdaDemoError(
                f"--strategy.budget={list(self.budget)} and --strategy.demos_per_task={list(self.demos_per_task)} "
                "both set the round's size: pass one"
            )

    def build(self, round_in_run: int) -> UniformStrategy:
        return UniformStrategy(self.demos_per_task.at(round_in_run) or 10, self.budget.at(round_in_run))


@dataclass
class UniformStrategy:
    demos_per_task: int
    budget: int | None
    name = "uniform"
    commits_by_task = True

    def start(self, ctx: RoundContext, resumed: dict | None) -> dict:
        return {"demos_per_task": self.demos_per_task, "budget": self.budget}

    def expand(self, ctx: RoundContext) -> list[TaskRoundRecord]:
        shares = split_evenly(self.budget, ctx.suite.tasks) if self.budget else None

        def one_task(task: str) -> TaskRoundRecord:
            n = shares[task] if shares else self.demos_per_task
            record = ctx.new_record(task, self.name, demos=n)
            ctx.collect_from_fresh_states(task, n, record)
            return record

        return ctx.run_tasks(one_task)
