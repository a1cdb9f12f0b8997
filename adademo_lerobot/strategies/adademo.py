"""AdaDemo (principles A + B): evaluate, collect where the policy fails, until E successes or CAP demos."""

from adademo_lerobot.algorithm import collect_on_failed_states
from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.strategies.base import RoundContext


class AdaDemoStrategy:
    name = "adademo"
    needs_policy = True
    collects_at_failed_states = True  # a correction needs a failed rollout to take over

    def expand_task(self, ctx: RoundContext, task: str) -> TaskRoundRecord:
        return collect_on_failed_states(ctx, task, ctx.new_record(task, self.name))
