"""`--strategy.type=adademo`: the paper's AdaDemo (principles A + B). Per task, evaluate the policy on fresh initial
states and collect a demonstration wherever it fails, until E successes or CAP demonstrations.

E is given per round (`--strategy.target_successes`), or picked from a round budget (`--strategy.budget`): the
largest E whose predicted total (N_k = E / SR_k - E, capped, from each task's success estimate over the earlier
rounds' evaluations) fits the budget, as the paper sets E "according to the budget".
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.imitability import demonstration_agreement
from adademo_lerobot.strategies.algorithm import InnerLoop, collect_on_failed_states
from adademo_lerobot.strategies.base import (
    DEFAULT_TARGET_SUCCESSES,
    PerRound,
    StrategyConfig,
    check_per_round,
    default_eval_bound,
    per_round,
    planned_demos,
)
from adademo_lerobot.strategies.estimates import DEFAULT_DECAY, estimated_success_rates

log = logging.getLogger(__name__)


def pick_target_successes(
    budget: int, success_rates: dict[str, float], caps: dict[str, int]
) -> tuple[int, dict[str, int]]:
    """The E whose predicted total (the paper's N_k = E / SR_k - E, capped at each task's CAP) comes closest to the
    budget without passing it (the smallest such E, once CAP stops the total from growing), and that prediction."""
    best, best_plan = 1, {t: planned_demos(1, sr, caps[t]) for t, sr in success_rates.items()}
    for target in range(2, budget + 1):
        plan = {t: planned_demos(target, sr, caps[t]) for t, sr in success_rates.items()}
        if sum(plan.values()) > budget:
            break
        if sum(plan.values()) > sum(best_plan.values()):
            best, best_plan = target, plan
    return best, best_plan


@StrategyConfig.register_subclass("adademo")
@dataclass
class AdaDemoConfig(StrategyConfig):
    """AdaDemo (the paper): demonstrations where the policy fails, until E successes or CAP demos per task."""

    description = "AdaDemo: collect where the policy fails, until E successes or CAP demos per task"
    needs_policy = True
    collects_at_failed_states = True

    # E_i: evaluation successes that end a task's collection (default 10); or leave it out and give a budget.
    target_successes: PerRound = per_round()
    # B_i: demonstrations per round; E is picked so that the predicted total fits it.
    budget: PerRound = per_round()
    # CAP_i: at most this many new demonstrations per task per round (the paper's per-round cap).
    max_demos_per_task: PerRound = per_round(50)
    # Bound on evaluation episodes per task and round, so a task the expert cannot solve still ends
    # (default 2 x (E + CAP)).
    max_eval_episodes_per_task: int | None = None
    # With a budget, in the success estimate: the last round's outcomes count fully, each round before it this
    # much less per round.
    posterior_decay: float = DEFAULT_DECAY
    # With a budget: a task whose first demonstrations disagree with each other (imitability score below 0.1,
    # `dataset/imitability.py`) gets at most an even share of the round, budget // tasks, instead of CAP; the
    # rest of the budget goes to the tasks a policy can learn from (principle A assumes more demonstrations help).
    limit_disagreeing: bool = False

    def validate(self) -> None:
        for name in ("target_successes", "budget"):
            check_per_round(name, getattr(self, name))
        check_per_round("max_demos_per_task", self.max_demos_per_task, required=True)
        if self.budget and self.target_successes:
            raise AdaDemoError(
                f"--strategy.budget={list(self.budget)} and --strategy.target_successes="
                f"{list(self.target_successes)} both set the round's size: pass one (with a budget, E is picked "
                "to fit it)"
            )
        check_eval_bound(self.max_eval_episodes_per_task)
        check_decay(self.posterior_decay)
        if self.limit_disagreeing and not self.budget:
            raise AdaDemoError(
                "--strategy.limit_disagreeing=true limits a task to an even share of the round's budget: give "
                "--strategy.budget too"
            )

    def can_plan(self) -> bool:
        return True

    def build(self, round_in_run: int) -> AdaDemoStrategy:
        return AdaDemoStrategy(
            self.target_successes.at(round_in_run),
            self.budget.at(round_in_run),
            self.max_demos_per_task.at(round_in_run),
            self.max_eval_episodes_per_task,
            self.posterior_decay,
            self.limit_disagreeing,
        )


def check_eval_bound(bound: int | None) -> None:
    if bound is not None and bound < 1:
        raise AdaDemoError(f"--strategy.max_eval_episodes_per_task must be >= 1, got {bound}")


def check_decay(decay: float) -> None:
    if not 0 < decay <= 1:
        raise AdaDemoError(f"--strategy.posterior_decay must be in (0, 1], got {decay}")


@dataclass
class AdaDemoStrategy:
    target_successes: int | None
    budget: int | None
    cap: int
    max_eval_episodes_per_task: int | None
    posterior_decay: float
    limit_disagreeing: bool = False
    caps: dict[str, int] = field(default_factory=dict, init=False)  # each task's CAP, fixed by `start`
    name = "adademo"
    commits_by_task = True

    def task_cap(self, task: str) -> int:
        return self.caps[task]

    def start(self, ctx: InnerLoop, resumed: dict | None) -> dict:
        """E for the round: given, the default, or picked from the budget (a resumed round keeps its pick, since
        the estimate would now include its own evaluations); each task's CAP (a resumed round keeps its limits)."""
        if resumed:  # the limits it journaled, none if it journaled none, whatever the flag says now
            limited = resumed.get("limited_tasks", {})
        else:
            limited = disagreeing_task_caps(ctx, self.budget, self.cap) if self.limit_disagreeing else {}
        self.caps = {**dict.fromkeys(ctx.tasks, self.cap), **limited}
        # A resumed round journals what it started with (the journal compares the two), a new one by the flag.
        journals_limits = "limited_tasks" in resumed if resumed else self.limit_disagreeing
        if self.target_successes is None and self.budget is not None:
            if resumed and resumed.get("target_successes") is not None:
                self.target_successes = resumed["target_successes"]
            else:
                rates = estimated_success_rates(ctx.root, ctx.round_index, ctx.tasks, self.posterior_decay)
                self.target_successes, plan = pick_target_successes(self.budget, rates, self.caps)
                log.info(
                    "budget %d: picked E=%d (predicted demos %s; total %d)",
                    self.budget, self.target_successes,
                    ", ".join(f"{t} {n}" for t, n in plan.items()), sum(plan.values()),
                )  # fmt: skip
                if sum(plan.values()) > self.budget:  # E is at least 1: the paper's rule has nothing smaller
                    log.info(
                        "note: even E=1 predicts %d demonstrations, over the budget of %d: the round may spend "
                        "more (a lower --strategy.max_demos_per_task bounds it; --strategy.type=budgeted spends "
                        "exactly B)", sum(plan.values()), self.budget,
                    )  # fmt: skip
        self.target_successes = self.target_successes or DEFAULT_TARGET_SUCCESSES
        self.max_eval_episodes_per_task = self.max_eval_episodes_per_task or default_eval_bound(
            self.target_successes, self.cap
        )
        return {
            "target_successes": self.target_successes,
            "max_demos_per_task": self.cap,
            "budget": self.budget,
            "max_eval_episodes_per_task": self.max_eval_episodes_per_task,
            **({"limited_tasks": limited} if journals_limits else {}),
        }

    def expand(self, ctx: InnerLoop) -> list[TaskRoundRecord]:
        def one_task(task: str) -> TaskRoundRecord:
            cap = self.task_cap(task)
            record = ctx.new_record(task, self.name, self.target_successes, cap)
            return collect_on_failed_states(
                ctx, task, record, self.target_successes, cap, self.max_eval_episodes_per_task
            )

        return ctx.run_tasks(one_task)


def disagreeing_task_caps(ctx: InnerLoop, budget: int, cap: int) -> dict[str, int]:
    """The CAP of each task whose first demonstrations disagree with each other: an even share of the budget
    (rounded down, so that the limited tasks' caps add up to no more than the budget; at least 1)."""
    share = min(cap, max(1, budget // len(ctx.tasks)))
    scored = {a.task: a for a in demonstration_agreement(ctx.root, ctx.tasks)}
    limited = {t: share for t in ctx.tasks if t in scored and scored[t].disagrees}
    for task in ctx.tasks:
        if task in limited:
            log.info(
                "note: %s's demonstrations disagree with each other: at most %d new ones this round",
                task,
                share,
            )
        elif task not in scored or scored[task].score is None:
            why = scored[task].reading if task in scored else "the dataset records no observation.state"
            log.info(
                "note: %s is not limited: whether its demonstrations agree cannot be told (%s)", task, why
            )
    return limited
