"""The budgeted strategy when policy rollouts cost something (`--strategy.rollout_cost=c`, in demonstrations).

On a robot every episode needs the scene reset, a policy rollout as much as a demonstration. With a rollout cost,
the round's budget B pays for both: expert attempts (kept or failed) cost 1, rollouts c (a correction,
`--demo_start=takeover`, continues its rollout's episode: no second cost), and the round stops when the next
rollout and the demonstration it may lead to would overspend. Evaluation goes only where a found failure
is worth its rollouts:

- each task's failure rate p has a Beta posterior (as the budgeted strategy keeps it: the earlier rounds'
  outcomes, decayed, then this round's); its optimistic value u, the posterior's 80th percentile
  (`--strategy.optimism`), decides. From no prior, with c = 1 and W = 3, at 0.8 two straight successes close a
  task for evaluation and three end its probes (`probe_unsure`, below); at 0.9 three and five (a 62 % task ends its
  probes on luck with probability 0.24 at 0.8, 0.09 at 0.9; a solved task costs two rollouts more);
- a task closes for evaluation once even u makes the expected rollout cost of its next failure, c / u, exceed what
  a demonstration at a failure is worth beyond one from a random state, W - 1 demonstrations (W =
  `--strategy.failure_worth`: the paper reaches Uniform's result with about a third of the data, W = 3). A task
  that keeps succeeding closes after a rollout or two instead of being evaluated to the bound. With corrections
  (`--demo_start=takeover`) a failure's answer continues its rollout and costs no episode of its own unless the
  expert fails from the takeover state (then it starts again from the initial state): a task is worth evaluating
  while u >= c / (W - a), a the share of the task's takeovers this round the expert failed from (0 until one
  fails; a = 1 without corrections gives c / (W - 1)). At c = 1 and W = 3 that is from 1/3 instead of 1/2, where
  a rollout's expected correction is worth what a fresh demonstration is, and the rollout also informs the
  posterior;
- the open task with the highest u is evaluated next (its failures are the likeliest cheap, principle A wants
  demos there; a task not yet tried has u = 0.8 under Beta(1, 1), so it comes before every task whose u is lower,
  but a task that keeps failing stays above it and can take most of the round: `split_episodes` below), one
  state at first and as many at once as it has found failures this round (at most `--eval.batch_size`);
- once no task is worth evaluating, the rest of the budget buys demonstrations from fresh initial states with no
  rollout (principle A alone): a fresh state is a failure with probability p, so such a demonstration is worth
  W p and pays while the task's posterior mean failure rate is at least 1 / W; the rest is split across those
  tasks in proportion to it (at most CAP each, as the budgeted split). Budget that no task is worth is left
  unspent, which is what the user saves;
- `--strategy.probe_unsure=true`: before a task is left without fresh demonstrations (its posterior mean failure
  rate under 1 / W), it is probed with one rollout at a time while even its optimistic value u is still at least
  1 / W. Without it a task that succeeds twice by luck (Beta(1, 1) then mean 1/4 < 1/3) gets nothing all round
  (MT10: reach-v3 at 62 % success, benchmarks/results/mt10_cost); a probe that fails is answered at once, as any
  failure is, so it is not lost;
- `--strategy.split_episodes=true`: instead of evaluating the task with the highest u until none is worth it and then
  splitting what is left, the round's budget (rollouts and expert attempts at their cost) is split across the tasks
  in proportion to each one's posterior mean failure rate, as the budgeted strategy splits demonstrations, and
  re-split after every outcome (a task that closes keeps what it spent); the task furthest below its share acts
  next, by the same rules: evaluated while a found failure is worth its rollouts, else a fresh-state demonstration
  while W p >= 1, else probed while unsure. Greedy evaluation gave most of a round to the one weakest task (MT10:
  peg-insert-side-v3 took 83 rollouts and 33 demonstrations while pick-place-v3 at 72 % got one demonstration);
- `--strategy.rank_states=knn` takes, for evaluation and for those fresh demonstrations, the candidate states a
  k-nearest-neighbour vote over every outcome seen so far (earlier rounds and this one) predicts most likely to
  fail, instead of the next random ones: demonstrations at predicted failures without a rollout. The ranked states
  fail more often than the task's states do, and the posterior counts their outcomes as random draws, so it
  overestimates a ranked task's failure rate (MT10: pick-place-v3 took 39 rollouts, benchmarks/results/
  mt10_cost_xeon.md). `--strategy.rank_states=knn_fresh` ranks only the fresh-state demonstrations (the
  likeliest failure of the next 8 fresh states, by the vote over every evaluated outcome) and evaluates random
  states, so the posterior stays an estimate of the task's failure rate.

Every decision depends only on journaled outcomes, so an interrupted round resumes to the same result. Without the
k-NN ranking the loop asks a round only for policy episodes and demonstrations (`algorithm.InnerLoop`; a seed never
evaluated is a fresh initial state), so a person at a robot runs it too (`adademo-record`: a new scene).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.seeds import expansion_state_seed, fresh_state_seed
from adademo_lerobot.dataset.ledger import read_round_evaluations
from adademo_lerobot.strategies.estimates import (
    allocate,
    count_outcomes,
    failure_mean,
    knn_failure_vote,
    prior_from_earlier_rounds,
)

if TYPE_CHECKING:
    from adademo_lerobot.strategies.algorithm import InnerLoop
    from adademo_lerobot.strategies.round_context import RoundContext

RANKINGS = ("random", "knn", "knn_fresh")
DEFAULT_FAILURE_WORTH = 3.0  # W: the paper reaches Uniform's result with about a third of the data
DEFAULT_OPTIMISM = 0.8  # the posterior quantile of the failure rate that opens, closes and orders the tasks
NEIGHBOURS = 5
MIN_OUTCOMES = 5  # outcomes (with at least one failure) before the k-NN ranks candidates
CANDIDATES = 8  # candidate states drawn per state evaluated, for ranking


def task_cost(record: TaskRoundRecord, rollout_cost: float) -> float:
    """What a task has spent this round, in demonstrations: every expert attempt, and every rollout at its cost.
    A correction (`--demo_start=takeover`) continues the rollout it corrects, in the same scene: its rollout paid
    for it (`core/costs.py`); a demonstration from the initial state after a failed takeover is one more."""
    expert_attempts = record.demos_added - record.corrections + record.expert_failures
    return expert_attempts + rollout_cost * record.eval_episodes


def round_cost(records: dict[str, TaskRoundRecord], rollout_cost: float) -> float:
    return sum(task_cost(r, rollout_cost) for r in records.values())


class FailureRanker:
    """Candidate initial states of one task in order of predicted failure: the share of failures among the k
    nearest evaluated states (standardized features), from every outcome of the earlier rounds and this one."""

    def __init__(self, ctx: RoundContext, task: str):
        self.ctx, self.task = ctx, task
        self._state_of: dict[int, np.ndarray] = {}
        self.states: list[np.ndarray] = []
        self.failed: list[bool] = []
        for r in range(1, ctx.round_index):
            for e in read_round_evaluations(ctx.root, r):
                if e.get("type") == "eval" and e["task"] == task:
                    self.add(e["seed"], not e["success"])

    def state(self, seed: int) -> np.ndarray:
        if seed not in self._state_of:
            state = self.ctx.suite.sample_initial_state(self.task, seed)
            self._state_of[seed] = np.asarray(state, dtype=np.float64)
        return self._state_of[seed]

    def add(self, seed: int, failed: bool) -> None:
        self.states.append(self.state(seed))
        self.failed.append(failed)

    def scores(self, seeds: list[int]) -> np.ndarray | None:
        """Predicted failure probability of each seed's state (None: too few outcomes to predict)."""
        failed = np.asarray(self.failed, dtype=np.float64)
        if len(failed) < MIN_OUTCOMES or not failed.any():
            return None
        query = np.stack([self.state(s) for s in seeds])
        return knn_failure_vote(np.stack(self.states), failed, query, NEIGHBOURS)


class PayingStrategy(Protocol):
    """What a round that pays for its rollouts reads of its strategy (`budgeted.BudgetedStrategy` with a rollout
    cost)."""

    name: str
    budget: int
    cap: int
    max_eval_episodes_per_task: int
    posterior_decay: float
    rollout_cost: float
    failure_worth: float
    optimism: float
    rank_states: str
    probe_unsure: bool
    split_episodes: bool


def expand_paying_for_rollouts(strategy: PayingStrategy, ctx: InnerLoop) -> list[TaskRoundRecord]:
    tasks, cap, c = ctx.tasks, strategy.cap, strategy.rollout_cost
    posterior = {
        t: prior_from_earlier_rounds(ctx.root, ctx.round_index, t, strategy.posterior_decay) for t in tasks
    }
    records = {t: ctx.new_record(t, strategy.name, cap=cap) for t in tasks}
    for t in tasks:
        records[t].extra = {
            "budget": strategy.budget,
            "prior": list(posterior[t]),
            "rollout_cost": c,
            "fresh_demos": 0,
        }
    rankers = {t: FailureRanker(ctx, t) for t in tasks} if strategy.rank_states != "random" else {}
    ranked_evaluations = strategy.rank_states == "knn"
    drawn = dict.fromkeys(tasks, 0)  # candidate states drawn so far (each is evaluated at most once)
    pool: dict[str, list[int]] = {t: [] for t in tasks}  # drawn, not yet evaluated

    def optimistic_failure(t: str) -> float:
        from scipy.stats import beta

        alpha, b = posterior[t]
        return float(beta.ppf(strategy.optimism, b, alpha))  # the failure rate's Beta(beta, alpha) quantile

    def answer_cost(t: str) -> float:
        """Expert episodes beyond the rollout that answering one of the task's failures costs: 1 (a demonstration
        from the initial state), or with corrections the share of this round's takeovers the expert failed from
        (each then starts again from the initial state), 0 until one fails."""
        if not ctx.corrects_failures:
            return 1.0
        r = records[t]
        requests = r.corrections + r.takeover_failures
        return r.takeover_failures / requests if requests else 0.0

    def evaluation_threshold(t: str) -> float:
        """A rollout costs c and fails with probability u; its answer costs a more and is worth W demonstrations
        from random states: worth it while u W >= c + u a, i.e. u >= c / (W - a) (c / (W - 1) without
        corrections)."""
        return c / (strategy.failure_worth - answer_cost(t))

    def refill(t: str) -> None:
        while len(pool[t]) < CANDIDATES * ctx.batch_size:
            pool[t].append(expansion_state_seed(ctx.seed, ctx.round_index, t, drawn[t]))
            drawn[t] += 1

    def next_states(t: str, n: int, ranked: bool) -> list[int]:
        if not ranked:
            seeds = [expansion_state_seed(ctx.seed, ctx.round_index, t, drawn[t] + j) for j in range(n)]
            drawn[t] += n
            return seeds
        refill(t)
        scores = rankers[t].scores(pool[t])
        order = list(range(len(pool[t]))) if scores is None else list(np.argsort(-scores, kind="stable"))
        chosen = [pool[t][i] for i in order[:n]]
        pool[t] = [s for s in pool[t] if s not in chosen]
        return chosen

    # knn_fresh: the fresh states drawn and not yet demonstrated from, per task
    fresh_pool: dict[str, list[int]] = {t: [] for t in tasks}

    def likeliest_failing_fresh_state(t: str) -> int:
        while len(fresh_pool[t]) < CANDIDATES:  # drawn so far: one per attempt made, plus the pool
            draw = fresh_draws[t] + len(fresh_pool[t])
            fresh_pool[t].append(fresh_state_seed(ctx.seed, ctx.round_index, t, draw))
        scores = rankers[t].scores(fresh_pool[t])
        return fresh_pool[t].pop(0 if scores is None else int(np.argmax(scores)))  # ties: the earliest drawn

    def demonstrate_from_fresh_state(t: str) -> None:
        """One expert attempt (paid whether kept or not) from the task's next fresh state, or with the k-NN from
        the candidate predicted likeliest to fail."""
        if ranked_evaluations:
            seed = next_states(t, 1, ranked=True)[0]
        elif t in rankers:
            seed = likeliest_failing_fresh_state(t)
        else:
            seed = fresh_state_seed(ctx.seed, ctx.round_index, t, fresh_draws[t])
        fresh_draws[t] += 1
        records[t].extra["fresh_demos"] += ctx.collect_demo(t, seed, records[t])
        ctx.progress(t, records[t])

    def evaluate(task: str, n: int) -> None:
        """Up to `n` rollouts of the task (within the batch, CAP and the evaluation bound), each failure answered
        by a demonstration at its state."""
        record = records[task]
        n = min(
            n,
            ctx.batch_size,
            cap - record.demos_added,
            strategy.max_eval_episodes_per_task - record.eval_episodes,
        )
        outcomes = ctx.evaluate(task, next_states(task, n, ranked=ranked_evaluations))
        ctx.ask_expert(task, [o.seed for o in outcomes if not o.success])
        posterior[task] = count_outcomes(ctx, task, record, outcomes, posterior[task], ctx.collect_demo)
        for outcome in outcomes if task in rankers else ():
            rankers[task].add(outcome.seed, not outcome.success)

    fresh_draws = dict.fromkeys(tasks, 0)

    def probe(task: str) -> None:
        records[task].extra["probes"] = records[task].extra.get("probes", 0) + 1
        evaluate(task, 1)

    def evaluate_likeliest_failure_first() -> None:
        """Evaluate the task with the highest u while one is worth it, then split what is left (principle A)."""
        while True:
            left = strategy.budget - round_cost(records, c)
            open_tasks = [t for t in tasks if records[t].demos_added < cap]
            # rollouts that can still pay for the demonstration each may need
            affordable = int(left // (c + 1))
            worth = {
                t: u
                for t in open_tasks
                if records[t].eval_episodes < strategy.max_eval_episodes_per_task
                and (u := optimistic_failure(t)) >= evaluation_threshold(t)
            }
            if worth and affordable >= 1:
                task = max(worth, key=lambda t: (worth[t], -records[t].eval_episodes, -tasks.index(t)))
                # one state at first, more as it fails
                evaluate(task, min(max(1, records[task].failures), affordable))
                continue
            # Principle A alone: fresh-state demonstrations where W p >= 1, split in proportion to p within CAP.
            weak = {
                t: m for t in open_tasks if strategy.failure_worth * (m := failure_mean(posterior[t])) >= 1
            }
            unsure = {
                t: u
                for t in open_tasks
                if strategy.probe_unsure
                and t not in weak
                and records[t].eval_episodes < strategy.max_eval_episodes_per_task
                and strategy.failure_worth * (u := optimistic_failure(t)) >= 1
            }
            # Learn whether it is weak before the fresh demonstrations are split.
            if unsure and affordable >= 1:
                probe(max(unsure, key=lambda t: (unsure[t], -tasks.index(t))))
                continue
            if not weak or left < 1:
                return
            share = allocate(int(left), weak, {t: cap - records[t].demos_added for t in weak})
            demonstrate_from_fresh_state(max(weak, key=lambda t: (share[t], weak[t], -tasks.index(t))))

    def split_episodes_by_failure() -> None:
        """The round's budget split across tasks by posterior mean failure rate; the task furthest below its share
        acts next (evaluate, else a fresh-state demonstration, else probe) until none can."""
        while True:
            left = strategy.budget - round_cost(records, c)
            affordable = int(left // (c + 1))  # a rollout and the demonstration it may lead to
            action: dict[str, str] = {}
            for t in tasks:
                r = records[t]
                if r.demos_added >= cap:
                    continue
                may_evaluate = r.eval_episodes < strategy.max_eval_episodes_per_task and affordable >= 1
                u, p = optimistic_failure(t), failure_mean(posterior[t])
                if may_evaluate and u >= evaluation_threshold(t):
                    action[t] = "evaluate"
                elif strategy.failure_worth * p >= 1 and left >= 1:
                    action[t] = "fresh"
                elif may_evaluate and strategy.probe_unsure and strategy.failure_worth * u >= 1:
                    action[t] = "probe"
            if not action:
                return
            # The budget the closed tasks did not spend is shared by the acting ones, by expected failure rate.
            free = strategy.budget - sum(task_cost(records[t], c) for t in tasks if t not in action)
            mass = sum(failure_mean(posterior[t]) for t in action)
            lacking = {t: free * failure_mean(posterior[t]) / mass - task_cost(records[t], c) for t in action}
            task = max(action, key=lambda t: (lacking[t], -tasks.index(t)))
            if action[task] == "evaluate":  # one state at first, more as it fails
                evaluate(task, min(max(1, records[task].failures), affordable))
            elif action[task] == "fresh":
                demonstrate_from_fresh_state(task)
            else:
                probe(task)

    if strategy.split_episodes:
        split_episodes_by_failure()
    else:
        evaluate_likeliest_failure_first()
    spent = round_cost(records, c)
    for t in tasks:
        r = records[t]
        r.cap_hit = r.demos_added >= cap
        r.eval_bound_hit = r.eval_episodes >= strategy.max_eval_episodes_per_task and not r.cap_hit
        r.extra.update(
            posterior=list(posterior[t]),
            posterior_success_mean=1 - failure_mean(posterior[t]),
            round_cost=spent,
            closed_as_not_worth=optimistic_failure(t) < evaluation_threshold(t),
            fresh_attempts=fresh_draws[t],
        )
    return [records[t] for t in tasks]
