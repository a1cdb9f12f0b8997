"""`--strategy.type=every_failure`: each round, per task, the policy runs from `rollouts_per_task` fresh initial
states and the expert demonstrates from every state where it failed (principle B with a fixed number of rollouts,
where AdaDemo stops a task after E successes). The package also registers an expert, `--collector.type=smoothed`
(`smoothed.py`): importing the package registers both."""

from __future__ import annotations

from dataclasses import dataclass

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import expansion_state_seed
from adademo_lerobot.strategies.algorithm import InnerLoop
from adademo_lerobot.strategies.base import StrategyConfig
from adademo_lerobot_example import smoothed  # noqa: F401  (registers --collector.type=smoothed)


@StrategyConfig.register_subclass("every_failure")
@dataclass
class EveryFailureConfig(StrategyConfig):
    """A demonstration at every failure of `rollouts_per_task` policy rollouts per task."""

    description = "every failure: a fixed number of rollouts per task, a demo from each failed state"
    needs_policy = True  # it runs the policy: --policy.path is required
    collects_at_failed_states = True  # so it also runs with a person at a robot (adademo-record)

    # Policy rollouts per task and round, each from a fresh initial state.
    rollouts_per_task: int = 10

    def validate(self) -> None:
        if self.rollouts_per_task < 1:
            raise AdaDemoError(
                f"--strategy.rollouts_per_task={self.rollouts_per_task}: give at least 1 rollout per task"
            )

    def build(self, round_in_run: int) -> EveryFailure:
        return EveryFailure(self.rollouts_per_task)


@dataclass
class EveryFailure:
    rollouts_per_task: int
    name = "every_failure"  # recorded in the ledger and as each new episode's adademo/source
    commits_by_task = True  # demos are committed task by task, in the suite's order

    def start(self, ctx: InnerLoop, resumed: dict | None) -> dict:
        return {"rollouts_per_task": self.rollouts_per_task}  # journaled: a resumed round gets it back

    def expand(self, ctx: InnerLoop) -> list[TaskRoundRecord]:
        def one_task(task: str) -> TaskRoundRecord:
            record = ctx.new_record(task, self.name)
            seeds = [
                expansion_state_seed(ctx.seed, ctx.round_index, task, k)
                for k in range(self.rollouts_per_task)
            ]
            outcomes = ctx.evaluate(task, seeds)
            # The experts may start on all the failed states at once (Ray workers); a person does one at a time.
            ctx.ask_expert(task, [o.seed for o in outcomes if not o.success])
            for outcome in outcomes:
                record.eval_episodes += 1
                if outcome.success:
                    record.successes += 1
                else:
                    record.failures += 1
                    ctx.collect_demo(task, outcome.seed, record)  # from that very state
                ctx.progress(task, record)
            return record

        return ctx.run_tasks(one_task)
