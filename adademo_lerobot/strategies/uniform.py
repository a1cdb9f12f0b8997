"""The paper's Uniform baseline: N new demos per task from fresh random initial states, no evaluation."""

from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.strategies.base import RoundContext


class UniformStrategy:
    name = "uniform"
    needs_policy = False
    collects_at_failed_states = False  # a correction needs a failed rollout to take over

    def expand_task(self, ctx: RoundContext, task: str) -> TaskRoundRecord:
        record = ctx.new_record(task, self.name)
        record.target_successes = record.max_demos_per_task = None
        record.demos_per_task = ctx.demos_for(task)
        ctx.collect_from_fresh_states(task, record.demos_per_task, record)
        return record
