"""Ablation A: as many demos per task as AdaDemo would allocate, but from fresh random initial states.

The allocation is the paper's estimate N_k = E / SR_k - E (capped at CAP), with SR_k measured on
`plan_episodes_per_task` evaluation episodes of this round's policy.
"""

from adademo_lerobot.records import TaskRoundRecord
from adademo_lerobot.seeds import plan_state_seeds
from adademo_lerobot.strategies.base import RoundContext, planned_demos


def estimate_success(ctx: RoundContext, task: str, record: TaskRoundRecord) -> float:
    """SR_k on the round's plan states (journaled like every evaluation); fills the record's counts."""
    outcomes = ctx.evaluate(
        task, plan_state_seeds(ctx.seed, ctx.round_index, task, ctx.plan_episodes_per_task)
    )
    record.eval_episodes = len(outcomes)
    record.successes = sum(o.success for o in outcomes)
    record.failures = record.eval_episodes - record.successes
    return record.successes / record.eval_episodes


class TaskOnlyStrategy:
    name = "task_only"
    needs_policy = True
    collects_at_failed_states = False  # a correction needs a failed rollout to take over

    def expand_task(self, ctx: RoundContext, task: str) -> TaskRoundRecord:
        record = ctx.new_record(task, self.name)
        sr = estimate_success(ctx, task, record)
        record.planned_demos = planned_demos(ctx.target_successes, sr, ctx.max_demos_per_task)
        ctx.collect_from_fresh_states(task, record.planned_demos, record)
        record.cap_hit = record.planned_demos >= ctx.max_demos_per_task
        return record
