"""AdaDemo, Algorithm 1 of the paper ("Adaptive Online Demo Expansion"), read top to bottom.

    Train a multi-task policy pi on D_0
    for each round i:
        choose E_i (target successes) for the budget
        for each task T_k:
            D_i^k = {}, c = 0
            repeat
                sample an initial state s of T_k; evaluate pi on s
                if pi failed on s:  D_i^k += G(s)        (principle B: demos where the policy fails)
                else:               c += 1
            until c = E_i                                (principle A: weak tasks get more demos)
        D = D_0 u ... u D_i;  re-train pi on D          (principle C: trajectory-uniform sampling)

`collect_on_failed_states` is the inner loop (lines 4-16) for one task, with the round's E and CAP and a bound on
evaluations (so a task the expert cannot solve still ends). The outer loop (train, rounds, retrain) is
`adademo_lerobot.loop.run`, which calls this through the `adademo` strategy. Evaluations run in batches no
larger than the fewest episodes that could end the loop, so batching never evaluates past the stopping point.
With a Ray executor the expert starts on all of a batch's failures at once and several tasks' loops run side by
side; every decision below is the same, so is the result.

`InnerLoop` is what this loop and the strategies that answer failed evaluations (`adademo`, `budgeted`) ask of a
round. Two contexts provide it: a simulated round (`strategies.base.RoundContext`: executors, a scripted or policy
expert) and a person's round on a robot (`record.PersonRound`); both keep their books (journal, ledger record,
counts) with `strategies.bookkeeping.JournaledRound`, so the same rule from the same flags drives both.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.seeds import expansion_state_seed

if TYPE_CHECKING:
    from adademo_lerobot.strategies.round_context import Outcome


class InnerLoop(Protocol):
    """A round as the inner loop sees it: initial states to evaluate the policy on, and an expert (a simulated one
    or a person) to answer each failure with a demonstration from that state; everything journaled."""

    seed: int  # the run's seed: with the round and the task it names every initial state
    round_index: int  # the dataset's round

    @property
    def batch_size(self) -> int:
        """Initial states evaluated at once (1: a person at one robot)."""

    @property
    def tasks(self) -> list[str]:
        """The round's tasks, in order."""

    @property
    def root(self) -> Path:
        """The dataset's folder (its earlier rounds' evaluations feed the success estimates)."""

    @property
    def corrects_failures(self) -> bool:
        """A failure is answered by a correction that continues its rollout in the same scene
        (`--demo_start=takeover`), not by a demonstration from the initial state."""

    def new_record(
        self,
        task: str,
        strategy: str,
        target_successes: int | None = None,
        cap: int | None = None,
        demos: int | None = None,
    ) -> TaskRoundRecord:
        """The ledger's record of `task` in this round, with the strategy's E, CAP and N (None where unused)."""

    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        """The policy's outcome from each seed's initial state (journaled ones are reused, not run again)."""

    def ask_expert(self, task: str, seeds: list[int]) -> None:
        """The expert may start on these failed states now (a person does one when `collect_demo` asks)."""

    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        """A demonstration from this failed state (at most one a round), counted in `record`; False if none came."""

    def progress(self, task: str, record: TaskRoundRecord) -> None:
        """The record changed (for a progress display)."""

    def run_tasks(self, work: Callable[[str], TaskRoundRecord]) -> list[TaskRoundRecord]:
        """`work(task)` for every task, the records in task order."""


def collect_on_failed_states(
    ctx: InnerLoop,
    task: str,
    record: TaskRoundRecord,
    E: int,  # noqa: N803  (the paper's names)
    CAP: int,  # noqa: N803
    max_evaluations: int,
) -> TaskRoundRecord:
    c, k = 0, 0  # successes so far, initial states sampled so far
    while c < E and record.demos_added < CAP and k < max_evaluations:
        batch_size = min(ctx.batch_size, E - c, CAP - record.demos_added, max_evaluations - k)
        seeds = [expansion_state_seed(ctx.seed, ctx.round_index, task, k + j) for j in range(batch_size)]
        outcomes = ctx.evaluate(task, seeds)  # line 9: evaluate pi on s
        ctx.ask_expert(
            task, [o.seed for o in outcomes if not o.success]
        )  # experts may start on all failures at once
        for outcome in outcomes:
            k += 1
            record.eval_episodes += 1
            if not outcome.success:  # line 10: pi failed on s
                record.failures += 1
                ctx.collect_demo(task, outcome.seed, record)  # lines 11-12: tau = G(s); D_i^k += tau
            else:
                c += 1  # line 14
                record.successes += 1
            ctx.progress(task, record)
    record.cap_hit = record.demos_added >= CAP
    record.eval_bound_hit = c < E and not record.cap_hit
    return record
