"""`--strategy.type=budgeted --strategy.budget=B`: AdaDemo's principles A and B with a round budget instead of E.

The paper sets E "according to the budget" by hand, and a task's share follows from a handful of evaluation
episodes. Here the round spends exactly B demonstrations (fewer only where the expert fails every draw, a task
reaches CAP, or the evaluation bound finds too few failures, and then it says so):

- each task's success rate is a Beta posterior over every expansion-round evaluation outcome seen so far (the
  earlier rounds' records: the last round's count fully, each round before it `posterior_decay` less per round,
  as the policy changed; never the fixed evaluation set, which is the test set), updated with every outcome of this
  round;
- the budget is split across tasks in proportion to each task's expected failure rate (the posterior mean of
  1 - SR), never more than CAP per task (`allocate`), and re-split after every evaluation batch;
- demonstrations come only from initial states where the policy failed (principle B): the task furthest below
  its share is evaluated, at most as many states at once as it still lacks, every failure is handed to the
  expert and every success updates the posterior, and so the split. Evaluation is spent only where
  demonstrations are planned, and only as long as it finds them.

With `at_failed_states=False` the same loop is ablation A with a budget (`--strategy.type=task_only
--strategy.budget=B`): the same evaluations, posterior and split, but each failure is answered by a demonstration
from the task's next fresh random initial state (Uniform's stream of states), so that budgeted minus it measures
principle B alone.

Every decision depends only on journaled outcomes, so an interrupted round resumes to the same result, and the
Ray executor gives the local one's.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import expansion_state_seed
from adademo_lerobot.strategies.adademo import check_decay, check_eval_bound
from adademo_lerobot.strategies.algorithm import InnerLoop
from adademo_lerobot.strategies.base import (
    PerRound,
    StrategyConfig,
    check_per_round,
    default_eval_bound,
    per_round,
)
from adademo_lerobot.strategies.costed import (
    DEFAULT_FAILURE_WORTH,
    DEFAULT_OPTIMISM,
    RANKINGS,
    expand_paying_for_rollouts,
)
from adademo_lerobot.strategies.estimates import (
    DEFAULT_DECAY,
    allocate,
    count_outcomes,
    failure_mean,
    prior_from_earlier_rounds,
)

log = logging.getLogger(__name__)


@StrategyConfig.register_subclass("budgeted")
@dataclass
class BudgetedConfig(StrategyConfig):
    """Exactly B demonstrations per round where the policy fails, split by each task's expected failure rate."""

    description = (
        "budgeted AdaDemo: exactly B demos per round where the policy fails, split by expected failure"
    )
    needs_policy = True
    collects_at_failed_states = True

    # B_i: demonstrations per round (required).
    budget: PerRound = per_round()
    # CAP_i: at most this many new demonstrations per task per round.
    max_demos_per_task: PerRound = per_round(50)
    # Bound on evaluation episodes per task and round (default 2 x (10 + CAP)).
    max_eval_episodes_per_task: int | None = None
    # The last round's evaluation outcomes count fully, each round before it this much less (1: all the same).
    posterior_decay: float = DEFAULT_DECAY
    # What a policy rollout costs, in demonstrations (a robot: about 1, a scene reset each): the budget then pays
    # for rollouts too, and evaluation goes only where a found failure is worth its rollouts (strategies/costed.py).
    rollout_cost: float | None = None
    # With a rollout cost: how many demonstrations from random states one at a failed state is worth.
    failure_worth: float = DEFAULT_FAILURE_WORTH
    # With a rollout cost: `random` states, or `knn`: the states predicted likeliest to fail first (evaluated and
    # demonstrated from), or `knn_fresh`: only the fresh-state demonstrations' (evaluations stay random).
    rank_states: str = "random"
    # With a rollout cost: probe a task with single rollouts before leaving it without fresh demonstrations, while
    # its failure rate may still be 1 / failure_worth or more (the posterior's 80th percentile).
    probe_unsure: bool = False
    # With a rollout cost: split the round's budget, rollouts included, across the tasks by expected failure rate
    # (each acts in turn, furthest below its share first) instead of evaluating the likeliest-failing task first.
    split_episodes: bool = False
    # With a rollout cost: the quantile of a task's posterior failure rate that decides whether it is still worth
    # evaluating or probing (higher: more successes before a task closes).
    optimism: float = DEFAULT_OPTIMISM

    def validate(self) -> None:
        check_per_round("budget", self.budget, required=True)
        check_per_round("max_demos_per_task", self.max_demos_per_task, required=True)
        check_eval_bound(self.max_eval_episodes_per_task)
        check_decay(self.posterior_decay)
        check_rollout_cost(
            self.rollout_cost,
            self.failure_worth,
            self.rank_states,
            self.probe_unsure,
            self.split_episodes,
            self.optimism,
        )

    def answers_failures_only(self) -> bool:
        return self.rollout_cost is None  # paying for rollouts, it also buys demos from fresh states

    def needs_a_simulator(self) -> str | None:
        # Paying for rollouts, its fresh-state demonstrations are a person's from a new scene; only the k-NN
        # ranking needs initial states a simulator samples.
        if self.rank_states == "random":
            return None
        return f"--strategy.rank_states={self.rank_states} ranks initial states a simulator samples"

    def build(self, round_in_run: int) -> BudgetedStrategy:
        cap = self.max_demos_per_task.at(round_in_run)
        bound = self.max_eval_episodes_per_task or default_eval_bound(None, cap)
        return BudgetedStrategy(
            self.budget.at(round_in_run),
            cap,
            bound,
            self.posterior_decay,
            rollout_cost=self.rollout_cost,
            failure_worth=self.failure_worth,
            rank_states=self.rank_states,
            probe_unsure=self.probe_unsure,
            split_episodes=self.split_episodes,
            optimism=self.optimism,
        )


def check_rollout_cost(
    rollout_cost: float | None,
    failure_worth: float,
    rank_states: str,
    probe_unsure: bool = False,
    split_episodes: bool = False,
    optimism: float = DEFAULT_OPTIMISM,
) -> None:
    if rollout_cost is None:
        options = (
            failure_worth != DEFAULT_FAILURE_WORTH,
            rank_states != "random",
            probe_unsure,
            split_episodes,
            optimism != DEFAULT_OPTIMISM,
        )
        if any(options):
            raise AdaDemoError(
                "--strategy.failure_worth, --strategy.rank_states, --strategy.probe_unsure, "
                "--strategy.split_episodes and --strategy.optimism are used with --strategy.rollout_cost: give "
                "the cost of a policy rollout in demonstrations (e.g. 1 on a robot), or drop them"
            )
        return
    if not math.isfinite(rollout_cost) or rollout_cost < 0:
        raise AdaDemoError(
            f"--strategy.rollout_cost must be a number >= 0 (what a policy rollout costs, in demonstrations: "
            f"about 1 on a robot), got {rollout_cost}"
        )
    if not failure_worth > 1:
        raise AdaDemoError(f"--strategy.failure_worth must be > 1 (demonstrations), got {failure_worth}")
    if not (isinstance(optimism, int | float) and 0.5 <= optimism < 1):
        raise AdaDemoError(
            f"--strategy.optimism must be a quantile in [0.5, 1) (0.8: three straight successes close a task, "
            f"0.9: five), got {optimism}"
        )
    if rank_states not in RANKINGS:
        raise AdaDemoError(
            f"--strategy.rank_states must be one of {', '.join(RANKINGS)}, got {rank_states!r}"
        )


@dataclass
class BudgetedStrategy:
    budget: int
    cap: int
    max_eval_episodes_per_task: int
    posterior_decay: float
    at_failed_states: bool = True  # principle B; False: ablation A (a fresh state per failure)
    name: str = "budgeted"
    rollout_cost: float | None = None
    failure_worth: float = DEFAULT_FAILURE_WORTH
    rank_states: str = "random"
    probe_unsure: bool = False
    split_episodes: bool = False
    optimism: float = DEFAULT_OPTIMISM
    commits_by_task = False  # one loop over the whole round: demos are committed in the order they arrive

    def start(self, ctx: InnerLoop, resumed: dict | None) -> dict:
        settings = {
            "budget": self.budget,
            "max_demos_per_task": self.cap,
            "max_eval_episodes_per_task": self.max_eval_episodes_per_task,
            "posterior_decay": self.posterior_decay,
        }
        if self.rollout_cost is not None:  # (rounds journaled before the option keep their settings)
            settings |= {
                "rollout_cost": self.rollout_cost,
                "failure_worth": self.failure_worth,
                "rank_states": self.rank_states,
            }
        # (rounds journaled before these options keep their settings)
        settings |= {k: True for k in ("probe_unsure", "split_episodes") if getattr(self, k)}
        if self.optimism != DEFAULT_OPTIMISM:
            settings["optimism"] = self.optimism
        return settings

    def first_split(
        self, root: Path, round_index: int, tasks: list[str]
    ) -> tuple[dict[str, tuple[float, float]], dict[str, int]]:
        """Each task's prior (the earlier rounds' evaluation outcomes) and the round's split of the budget under
        it, before this round evaluates anything (adademo-record prints it as the round's plan)."""
        prior = {t: prior_from_earlier_rounds(root, round_index, t, self.posterior_decay) for t in tasks}
        split = allocate(
            self.budget, {t: failure_mean(prior[t]) for t in tasks}, dict.fromkeys(tasks, self.cap)
        )
        return prior, split

    def expand(self, ctx: InnerLoop) -> list[TaskRoundRecord]:
        if self.rollout_cost is not None:
            return expand_paying_for_rollouts(self, ctx)
        tasks, budget, cap = ctx.tasks, self.budget, self.cap
        posterior, first_plan = self.first_split(ctx.root, ctx.round_index, tasks)
        records = {t: ctx.new_record(t, self.name, cap=cap) for t in tasks}
        for t in tasks:
            records[t].planned_demos = first_plan[t]
            records[t].extra = {"budget": budget, "prior": list(posterior[t])}
        sampled = dict.fromkeys(tasks, 0)
        fresh_draws = dict.fromkeys(tasks, 0)  # ablation A: the next fresh initial state of each task

        def answer(task: str, seed: int, record: TaskRoundRecord) -> None:
            if self.at_failed_states:  # principle B: only where the policy failed
                ctx.collect_demo(task, seed, record)
            else:
                # ablation A: a simulated round's (RoundContext) next fresh state
                fresh_draws[task] = ctx.collect_from_next_fresh_state(task, fresh_draws[task], record)

        while sum(r.demos_added for r in records.values()) < budget:
            open_tasks = [
                t
                for t in tasks
                if records[t].demos_added < cap and sampled[t] < self.max_eval_episodes_per_task
            ]
            if not open_tasks:
                break
            # The round's split under what is known now (a closed task keeps what it has), and who lacks most.
            caps = {t: cap if t in open_tasks else records[t].demos_added for t in tasks}
            share = allocate(budget, {t: failure_mean(posterior[t]) for t in tasks}, caps)
            lacking = {t: share[t] - records[t].demos_added for t in open_tasks}
            if max(lacking.values()) <= 0:  # tasks over their share hold the rest: split what is left
                left = budget - sum(r.demos_added for r in records.values())
                lacking = allocate(
                    left,
                    {t: failure_mean(posterior[t]) for t in open_tasks},
                    {t: cap - records[t].demos_added for t in open_tasks},
                )
            task = max(open_tasks, key=lambda t: (lacking[t], -tasks.index(t)))
            record = records[task]
            n = min(
                ctx.batch_size,
                lacking[task],
                self.max_eval_episodes_per_task - sampled[task],
                budget - sum(r.demos_added for r in records.values()),
            )
            seeds = [
                expansion_state_seed(ctx.seed, ctx.round_index, task, sampled[task] + j) for j in range(n)
            ]
            outcomes = ctx.evaluate(task, seeds)
            if self.at_failed_states:
                ctx.ask_expert(task, [o.seed for o in outcomes if not o.success])
            sampled[task] += len(outcomes)
            posterior[task] = count_outcomes(ctx, task, record, outcomes, posterior[task], answer)
        spent = sum(r.demos_added for r in records.values())
        for t in tasks:
            r = records[t]
            r.cap_hit = r.demos_added >= cap
            r.eval_bound_hit = sampled[t] >= self.max_eval_episodes_per_task and not r.cap_hit
            r.extra.update(
                posterior=list(posterior[t]),
                posterior_success_mean=1 - failure_mean(posterior[t]),
                round_spent=spent,
            )
        if spent < budget:
            blocked = [t for t in tasks if records[t].cap_hit or records[t].eval_bound_hit]
            log.info(
                "note: round %d spent %d of its budget of %d demonstrations: %s reached CAP or the evaluation "
                "bound (the expert failed every draw or the policy stopped failing)",
                ctx.round_index, spent, budget, ", ".join(blocked),
            )  # fmt: skip
        return [records[t] for t in tasks]
