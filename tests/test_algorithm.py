"""Fast unit tests of Algorithm 1's inner loop, the task-only plan, the journal and the ledger.

The loop, the plan, the journal and the ledger are the real code; the round context they talk to is a small
in-memory one whose policy outcomes and expert results are scripted, so every stopping branch can be checked
with exact counts in milliseconds. The integration tests (test_expand.py) run the same code on real simulation.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import pytest

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import expansion_state_seed, plan_state_seeds
from adademo_lerobot.dataset.ledger import RoundJournal, append_ledger, read_ledger
from adademo_lerobot.strategies.algorithm import collect_on_failed_states
from adademo_lerobot.strategies.base import planned_demos
from adademo_lerobot.strategies.round_context import Outcome
from adademo_lerobot.strategies.task_only import TaskOnlyStrategy


@dataclass
class ScriptedRound:
    """The part of `RoundContext` the strategies use, with scripted policy outcomes ("F" fail / "S" success per
    sampled state, in order) and scripted expert results (False where the expert fails that state)."""

    outcomes: str
    target_successes: int
    max_demos_per_task: int
    max_eval_episodes_per_task: int
    batch_size: int = 4
    expert_fails_on: set[int] = field(default_factory=set)  # positions k (in sampling order) the expert fails
    seed: int = 0
    round_index: int = 1
    plan_episodes_per_task: int = 10
    evaluated: list[int] = field(default_factory=list)  # seeds, in the order they were evaluated
    batches: list[int] = field(default_factory=list)
    collected: list[int] = field(default_factory=list)  # seeds the expert was asked about
    fresh_requests: list[int] = field(default_factory=list)
    asked: list[int] = field(default_factory=list)  # seeds the expert was started on ahead of time

    def __post_init__(self):
        self._position: dict[int, int] = {}

    def ask_expert(self, task: str, seeds: list[int]) -> None:
        self.asked += seeds

    def new_record(
        self, task: str, strategy: str, target_successes=None, cap=None, demos=None
    ) -> TaskRoundRecord:
        return TaskRoundRecord(self.round_index, task, strategy, target_successes, cap, demos, None)

    def run_tasks(self, work):
        return [work("reach-v3")]

    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        self.batches.append(len(seeds))
        out = []
        for s in seeds:
            k = self._position.setdefault(s, len(self._position))
            self.evaluated.append(s)
            out.append(Outcome(s, self.outcomes[k] == "S"))
        return out

    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        self.collected.append(seed)
        if self._position[seed] in self.expert_fails_on:
            record.expert_failures += 1
            return False
        record.demos_added += 1
        return True

    def collect_from_fresh_states(self, task: str, n: int, record: TaskRoundRecord) -> None:
        self.fresh_requests.append(n)
        record.demos_added += n

    def progress(self, task, record) -> None:
        pass


@pytest.mark.parametrize("context", ["strategies.round_context:RoundContext", "loop.robot_round:PersonRound"])
def test_both_round_contexts_provide_the_inner_loop(context):
    """A simulated round and a person's are the same `InnerLoop` (members and their parameters), and keep their
    books in the same place."""
    import importlib
    import inspect

    from adademo_lerobot.strategies.algorithm import InnerLoop
    from adademo_lerobot.strategies.bookkeeping import JournaledRound

    module, name = context.split(":")
    cls = getattr(importlib.import_module(f"adademo_lerobot.{module}"), name)
    assert issubclass(cls, JournaledRound)
    for member in InnerLoop.__protocol_attrs__:
        declared = any(member in getattr(k, "__annotations__", {}) for k in cls.__mro__)
        assert hasattr(cls, member) or declared, f"{name} lacks {member}"
        wanted = getattr(InnerLoop, member, None)
        if inspect.isfunction(wanted):
            assert list(inspect.signature(getattr(cls, member)).parameters) == list(
                inspect.signature(wanted).parameters
            ), f"{name}.{member}"


def run_loop(ctx: ScriptedRound) -> TaskRoundRecord:
    record = ctx.new_record("reach-v3", "adademo", ctx.target_successes, ctx.max_demos_per_task)
    return collect_on_failed_states(
        ctx, "reach-v3", record, ctx.target_successes, ctx.max_demos_per_task, ctx.max_eval_episodes_per_task
    )


def seeds(n: int, task: str = "reach-v3") -> list[int]:
    return [expansion_state_seed(0, 1, task, k) for k in range(n)]


def test_stops_at_e_successes_collecting_on_every_failure_before():
    ctx = ScriptedRound(
        "FFSFSS" + "F" * 20, target_successes=3, max_demos_per_task=10, max_eval_episodes_per_task=50
    )
    r = run_loop(ctx)
    assert (r.eval_episodes, r.successes, r.failures, r.demos_added) == (6, 3, 3, 3)
    assert ctx.evaluated == seeds(6)  # the loop's own samples, in order, none beyond the stopping point
    assert ctx.collected == [seeds(6)[k] for k in (0, 1, 3)]  # demos exactly from the failed states
    assert ctx.asked == ctx.collected  # the expert was started ahead only on states it is then asked about
    assert not r.cap_hit and not r.eval_bound_hit


def test_stops_at_cap_demos():
    ctx = ScriptedRound("F" * 30, target_successes=5, max_demos_per_task=4, max_eval_episodes_per_task=50)
    r = run_loop(ctx)
    assert (r.eval_episodes, r.successes, r.demos_added) == (4, 0, 4)
    assert r.cap_hit and not r.eval_bound_hit


def test_stops_at_the_evaluation_bound_when_the_expert_keeps_failing():
    ctx = ScriptedRound(
        "F" * 30,
        target_successes=5,
        max_demos_per_task=4,
        max_eval_episodes_per_task=7,
        expert_fails_on=set(range(30)),
    )
    r = run_loop(ctx)
    assert (r.eval_episodes, r.successes, r.failures, r.demos_added, r.expert_failures) == (7, 0, 7, 0, 7)
    assert r.eval_bound_hit and not r.cap_hit


def test_expert_failures_do_not_count_towards_cap():
    ctx = ScriptedRound(
        "FFFFFFS" + "S" * 10,
        target_successes=2,
        max_demos_per_task=3,
        max_eval_episodes_per_task=50,
        expert_fails_on={1, 2},
    )
    r = run_loop(ctx)
    # Failures at 0..5: demos at 0, 3, 4 (CAP=3 reached at k=4), expert failed at 1, 2.
    assert (r.eval_episodes, r.demos_added, r.expert_failures, r.successes) == (5, 3, 2, 0)
    assert r.cap_hit


def test_batches_never_evaluate_past_a_possible_stopping_point():
    ctx = ScriptedRound(
        "SSSSSSSSSS", target_successes=6, max_demos_per_task=10, max_eval_episodes_per_task=50, batch_size=4
    )
    run_loop(ctx)
    assert ctx.batches == [4, 2]  # after 4 successes only 2 more can be needed
    ctx = ScriptedRound(
        "F" * 10, target_successes=9, max_demos_per_task=3, max_eval_episodes_per_task=50, batch_size=8
    )
    run_loop(ctx)
    assert ctx.batches == [3]  # 3 failures fill CAP=3


def test_task_only_plans_the_papers_estimate_and_collects_from_fresh_states(tmp_path):
    ctx = ScriptedRound(
        "SFFSFFFFFF",
        target_successes=4,
        max_demos_per_task=50,
        max_eval_episodes_per_task=50,
        plan_episodes_per_task=10,
    )
    (r,) = TaskOnlyStrategy(4, 50, 10).expand(ctx)
    assert ctx.evaluated == plan_state_seeds(0, 1, "reach-v3", 10)
    assert (r.eval_episodes, r.successes, r.failures) == (10, 2, 8)
    assert r.planned_demos == 16 == planned_demos(4, 0.2, 50)  # 4 / 0.2 - 4
    assert ctx.fresh_requests == [16] and not r.cap_hit
    ctx = ScriptedRound("F" * 10, target_successes=4, max_demos_per_task=7, max_eval_episodes_per_task=50)
    (r,) = TaskOnlyStrategy(4, 7, 10).expand(ctx)
    assert r.planned_demos == 7 and r.cap_hit  # SR 0 gets CAP


def test_planned_demos_formula():
    assert planned_demos(10, 0.5, 100) == 10
    assert planned_demos(10, 1.0, 100) == 0
    assert planned_demos(10, 0.0, 7) == 7
    assert planned_demos(5, 0.3, 100) == 12  # ceil(5 / 0.3 - 5) = ceil(11.67)
    assert planned_demos(5, 0.05, 20) == 20


def test_journal_keeps_its_index_in_memory_and_on_disk(tmp_path):
    journal = RoundJournal(tmp_path, 3)
    journal.start({"strategy": "adademo", "seed": 0})
    journal.append(
        {"type": "eval", "task": "a", "seed": 11, "success": False, "steps": 5},
        {"type": "eval", "task": "b", "seed": 12, "success": True, "steps": 7},
    )
    journal.append(
        {"type": "expert_failure", "task": "a", "seed": 11, "attempts": 3, "steps": 9, "initial_state": [0.0]}
    )
    journal.append(
        {"type": "time", "task": "a", "seconds": 1.5}, {"type": "time", "task": "a", "seconds": 0.5}
    )
    assert set(journal.evaluations("a")) == {11} and journal.evaluations("b")[12]["success"] is True
    assert set(journal.expert_failures("a")) == {11} and journal.seconds("a") == 2.0
    # A kill tears the last line: a fresh reader sees everything before it, the same as memory.
    with open(journal.path, "a") as f:
        f.write('{"type": "eval", "task": "a", "se')
    reread = RoundJournal(tmp_path, 3)
    assert reread.evaluations("a") == journal.evaluations("a") and reread.seconds("a") == 2.0
    with pytest.raises(AdaDemoError, match="other settings"):
        reread.start({"strategy": "uniform", "seed": 0})
    assert RoundJournal.in_progress(tmp_path) == [3]
    reread.finish()
    assert RoundJournal.in_progress(tmp_path) == [] and reread.archive_path.exists()


def test_a_round_journaled_before_a_takeover_field_existed_resumes_as_that_field_s_default(tmp_path):
    from adademo_lerobot.collectors.takeover import TakeoverArgs
    from adademo_lerobot.loop.run_state import FIELDS_WITHOUT_A_PAST_DEFAULT, config_field_defaults

    defaults = TakeoverArgs().to_dict()
    for name in defaults:
        journal = RoundJournal(tmp_path / name, 1)
        older = {k: v for k, v in defaults.items() if k != name}
        journal.start({"strategy": "budgeted", "demo_start": "takeover", "takeover": older})
        now = {"strategy": "budgeted", "demo_start": "takeover", "takeover": defaults}
        with pytest.raises(AdaDemoError, match="other settings"):  # without the defaults it is another round
            RoundJournal(tmp_path / name, 1).start(now)
        if name in FIELDS_WITHOUT_A_PAST_DEFAULT["takeover"]:  # older rounds did otherwise: refused still
            with pytest.raises(AdaDemoError, match="other settings"):
                RoundJournal(tmp_path / name, 1).start(now, field_defaults=config_field_defaults({}))
        else:
            RoundJournal(tmp_path / name, 1).start(now, field_defaults=config_field_defaults({}))
    journal = RoundJournal(tmp_path / "changed", 1)
    journal.start({"strategy": "budgeted", "takeover": {k: v for k, v in defaults.items() if k != "rule"}})
    changed = {"strategy": "budgeted", "takeover": defaults | {"threshold": defaults["threshold"] + 1}}
    with pytest.raises(
        AdaDemoError, match="takeover.threshold: 1.5 -> 2.5"
    ):  # a value set otherwise: refused
        RoundJournal(tmp_path / "changed", 1).start(changed, field_defaults=config_field_defaults({}))


def test_a_round_journaled_before_a_collector_field_existed_resumes_as_that_field_s_default(tmp_path):
    from adademo_lerobot.collectors import PlannerCollectorConfig
    from adademo_lerobot.loop.run_state import config_field_defaults

    now = PlannerCollectorConfig(samples=8).to_dict()
    field_defaults = config_field_defaults({"collector": now})
    older = {k: v for k, v in now.items() if k != "plan_decay"}  # journaled before plan_decay existed
    RoundJournal(tmp_path, 1).start({"strategy": "adademo", "collector": older})
    RoundJournal(tmp_path, 1).start({"strategy": "adademo", "collector": now}, field_defaults=field_defaults)
    decayed = now | {"plan_decay": 0.5}  # the older round planned without decay
    with pytest.raises(AdaDemoError, match="collector.plan_decay: 0.0 -> 0.5"):
        RoundJournal(tmp_path, 1).start(
            {"strategy": "adademo", "collector": decayed}, field_defaults=field_defaults
        )
    with pytest.raises(AdaDemoError, match="collector.type: 'planner' -> 'scripted'"):
        scripted = {"strategy": "adademo", "collector": {"type": "scripted", "max_attempts": 3}}
        RoundJournal(tmp_path, 1).start(scripted, field_defaults=field_defaults)


def test_ledger_appends_whole_rounds_once(tmp_path):
    records = [
        TaskRoundRecord(
            1, t, "adademo", 5, 10, None, "ckpt", eval_episodes=4, successes=1, failures=3, demos_added=3
        )
        for t in ("a", "b")
    ]
    append_ledger(tmp_path, records)
    rows = read_ledger(tmp_path)
    assert [(r["round"], r["task"], r["demos_added"]) for r in rows] == [(1, "a", 3), (1, "b", 3)]
    with pytest.raises(AdaDemoError, match="already in the ledger"):
        append_ledger(tmp_path, records[:1])
    assert len(read_ledger(tmp_path)) == 2
    append_ledger(tmp_path, [TaskRoundRecord(2, "a", "uniform", None, None, 4, None, demos_added=4)])
    assert [
        json.loads(line)["round"]
        for line in (tmp_path / "meta/adademo/rounds.jsonl").read_text().splitlines()
    ] == [1, 1, 2]


# -- the budgeted strategy ------------------------------------------------------------------------------------


@dataclass
class BudgetRound:
    """A round context for the budgeted strategy: per task, scripted outcomes in sampling order ("F"/"S") and
    the positions where the expert fails."""

    outcomes: dict[str, str]
    budget: int
    max_demos_per_task: int = 50
    max_eval_episodes_per_task: int = 100
    batch_size: int = 4
    expert_fails_on: dict[str, set] = field(default_factory=dict)
    root: str = "/nonexistent"  # no earlier rounds: every prior is Beta(1, 1)
    seed: int = 0
    round_index: int = 1
    posterior_decay: float = 0.5
    # --demo_start=takeover: a failure is answered by a correction that continues its rollout; where the expert
    # fails (`expert_fails_on`) it is a takeover failure, then a demonstration from the initial state.
    corrects_failures: bool = False

    def __post_init__(self):
        self.tasks = list(self.outcomes)
        self.suite = type("Suite", (), {"tasks": self.tasks})()
        self.dataset = type("Dataset", (), {"root": self.root})()
        self.evaluated = {t: [] for t in self.outcomes}
        self.collected = {t: [] for t in self.outcomes}
        self.fresh = {t: [] for t in self.outcomes}
        self._position = {t: {} for t in self.outcomes}

    def new_record(self, task, strategy, target_successes=None, cap=None, demos=None):
        return TaskRoundRecord(self.round_index, task, strategy, target_successes, cap, demos, None)

    def strategy(self, **options):
        from adademo_lerobot.strategies.budgeted import BudgetedStrategy

        return BudgetedStrategy(
            self.budget,
            self.max_demos_per_task,
            self.max_eval_episodes_per_task,
            self.posterior_decay,
            **options,
        )

    def collect_from_next_fresh_state(self, task, draw, record):
        self.fresh[task].append(draw)
        record.demos_added += 1
        return draw + 1

    def evaluate(self, task, seeds):
        out = []
        for s in seeds:
            k = self._position[task].setdefault(s, len(self._position[task]))
            self.evaluated[task].append(s)
            out.append(Outcome(s, self.outcomes[task][k] == "S"))
        return out

    def ask_expert(self, task, seeds):
        pass

    def collect_demo(self, task, seed, record):
        if seed not in self._position[task]:  # a state never evaluated: a fresh demonstration
            self.fresh[task].append(seed)
            record.demos_added += 1
            return True
        self.collected[task].append(seed)
        expert_fails = self._position[task][seed] in self.expert_fails_on.get(task, set())
        if expert_fails and not self.corrects_failures:
            record.expert_failures += 1
            return False
        record.demos_added += 1
        record.corrections += self.corrects_failures and not expert_fails
        record.takeover_failures += expert_fails
        return True

    def progress(self, task, record):
        pass

    def run_tasks(self, one_task):
        return [one_task(t) for t in self.tasks]


def test_allocate_splits_exactly_in_proportion_within_caps():
    from adademo_lerobot.strategies.estimates import allocate

    assert allocate(10, {"a": 0.5, "b": 0.3, "c": 0.2}, {"a": 10, "b": 10, "c": 10}) == {
        "a": 5,
        "b": 3,
        "c": 2,
    }
    assert allocate(10, {"a": 0.9, "b": 0.05, "c": 0.05}, {"a": 4, "b": 10, "c": 10}) == {
        "a": 4,
        "b": 3,
        "c": 3,
    }
    assert allocate(3, {"a": 1.0, "b": 1.0}, {"a": 5, "b": 5}) == {"a": 2, "b": 1}  # ties: the earlier task
    assert allocate(20, {"a": 1.0, "b": 1.0}, {"a": 4, "b": 5}) == {"a": 4, "b": 5}  # all caps: 9 < 20
    for total in range(0, 30):
        split = allocate(total, {"a": 0.7, "b": 0.2, "c": 0.1}, {"a": 8, "b": 8, "c": 8})
        assert sum(split.values()) == min(total, 24) and max(split.values()) <= 8


def test_budgeted_spends_exactly_the_budget_on_failed_states_weak_tasks_first():
    ctx = BudgetRound(
        {
            "easy": "SSSSSSSSFSSSSSSSSSSSSSSSS" * 4,
            "hard": "FFFSFFFFFFFFFFFFFFFFFFFF" * 4,
            "mid": "SFSFSFSFSFSFSFSFSFSFSF" * 4,
        },
        budget=12,
    )
    records = {r.task: r for r in ctx.strategy().expand(ctx)}
    assert sum(r.demos_added for r in records.values()) == 12
    assert records["hard"].demos_added > records["mid"].demos_added > records["easy"].demos_added
    for task, r in records.items():  # every demo from a state the policy failed, every evaluation accounted
        positions = [ctx._position[task][s] for s in ctx.collected[task]]
        assert all(ctx.outcomes[task][k] == "F" for k in positions)
        assert r.eval_episodes == len(ctx.evaluated[task]) == r.successes + r.failures
        assert r.failures == r.demos_added + r.expert_failures
        a, b = r.extra["posterior"]
        assert (a, b) == (1 + r.successes, 1 + r.failures)  # the posterior counts every outcome of the round
        assert r.planned_demos is not None and r.extra["round_spent"] == 12
    assert records["hard"].planned_demos == records["easy"].planned_demos  # Beta(1, 1): an even first split


def test_budgeted_falls_short_only_where_the_expert_fails_and_says_so(caplog):
    ctx = BudgetRound(
        {"a": "F" * 40, "b": "F" * 40},
        budget=10,
        max_demos_per_task=50,
        max_eval_episodes_per_task=8,
        expert_fails_on={"b": set(range(40))},
    )
    with caplog.at_level("INFO", logger="adademo_lerobot"):
        records = {r.task: r for r in ctx.strategy().expand(ctx)}
    assert records["b"].demos_added == 0 and records["b"].eval_bound_hit
    assert records["a"].demos_added == 8 and records["a"].eval_bound_hit  # bounded too: 8 of the 10
    assert "spent 8 of its budget of 10" in caplog.text


def test_budgeted_prior_comes_from_earlier_rounds_evaluations_with_decay(tmp_path):
    from adademo_lerobot.strategies.estimates import prior_from_earlier_rounds

    for r, outcomes in ((1, [True, False, False, False]), (2, [True, True])):
        journal = RoundJournal(tmp_path, r)
        journal.append(
            *(
                {"type": "eval", "task": "a", "seed": i, "success": s, "steps": 1}
                for i, s in enumerate(outcomes)
            )
        )
        journal.finish()
    # round 3: round 2 weighs 1, round 1 weighs 0.5
    assert prior_from_earlier_rounds(tmp_path, 3, "a") == (1 + 2 + 0.5 * 1, 1 + 0 + 0.5 * 3)
    assert prior_from_earlier_rounds(tmp_path, 3, "b") == (1.0, 1.0)
    assert prior_from_earlier_rounds(tmp_path, 3, "a", decay=1.0) == (1 + 3, 1 + 3)


def test_the_papers_e_is_picked_to_fit_a_budget():
    from adademo_lerobot.strategies.adademo import pick_target_successes

    target, plan = pick_target_successes(20, {"a": 0.5, "b": 0.25}, caps={"a": 50, "b": 50})
    assert target == 5 and plan == {"a": 5, "b": 15}  # E=6 would need 6 + 18 = 24 > 20
    target, plan = pick_target_successes(20, {"a": 0.5, "b": 0.0}, caps={"a": 8, "b": 8})
    assert target == 8 and plan == {"a": 8, "b": 8}  # SR 0 gets CAP; past E=8 CAP stops the total growing


def test_a_budget_even_e_1_overruns_is_said(caplog):
    from adademo_lerobot.strategies.adademo import AdaDemoStrategy

    ctx = BudgetRound({f"t{i}": "F" * 10 for i in range(10)}, budget=5)  # no earlier round: every SR 0.5
    with caplog.at_level("INFO"):
        AdaDemoStrategy(None, 5, 20, 100, 0.5).start(ctx, None)
    assert "note: even E=1 predicts 10 demonstrations, over the budget of 5" in caplog.text
    caplog.clear()
    with caplog.at_level("INFO"):
        AdaDemoStrategy(None, 10, 20, 100, 0.5).start(ctx, None)
    assert "picked E=1" in caplog.text and "note:" not in caplog.text


def test_the_papers_e_is_picked_with_each_tasks_own_cap():
    from adademo_lerobot.strategies.adademo import pick_target_successes

    # b never succeeds, so it always gets its CAP; with 3 instead of 50, E grows until a's share fills the rest.
    target, plan = pick_target_successes(20, {"a": 0.5, "b": 0.0}, caps={"a": 50, "b": 3})
    assert target == 17 and plan == {"a": 17, "b": 3}


def test_adademo_limits_a_task_whose_demonstrations_disagree_to_an_even_share(tmp_path, caplog):
    """`--strategy.limit_disagreeing=true` on a real dataset: 10 scripted demonstrations of reach-v3 and of push-v3,
    push's actions then drawn at random in the files. A round where the policy fails every state: reach collects to
    CAP, push only to its even share of the budget; the round's settings journal the limit, and a resumed round
    keeps it rather than scoring again."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq
    from conftest import run_cli

    from adademo_lerobot.dataset.metadata import data_files, read_episode_metadata
    from adademo_lerobot.strategies.adademo import AdaDemoStrategy, disagreeing_task_caps

    root = tmp_path / "demo"
    run_cli(
        "adademo-collect", "--suite.type=metaworld", "--suite.tasks=reach-v3,push-v3", "--episodes_per_task=10",
        "--dataset.repo_id=local/demo", f"--dataset.root={root}", "--seed=0",
    )  # fmt: skip
    episodes = read_episode_metadata(root)
    push = episodes[episodes.task == "push-v3"]
    starts_and_ends = zip(push.dataset_from_index, push.dataset_to_index, strict=True)
    push_frames = np.concatenate([np.arange(a, b) for a, b in starts_and_ends])
    rng = np.random.default_rng(0)
    for path in data_files(root):
        frames = pq.read_table(path)
        actions = np.asarray(frames.column("action").to_pylist(), dtype=np.float32)
        mine = np.isin(frames.column("index").to_numpy(), push_frames)
        actions[mine] = rng.uniform(-1, 1, size=(int(mine.sum()), actions.shape[1]))
        column = pa.FixedSizeListArray.from_arrays(pa.array(actions.ravel()), actions.shape[1])
        pq.write_table(frames.set_column(frames.schema.get_field_index("action"), "action", column), path)

    def round_with(limit: bool, resumed: dict | None = None, budget: int = 30):
        ctx = BudgetRound({"reach-v3": "F" * 100, "push-v3": "F" * 100}, budget=budget, root=str(root))
        strategy = AdaDemoStrategy(None, budget, 20, 100, 0.5, limit_disagreeing=limit)
        settings = strategy.start(ctx, resumed)
        return settings, {r.task: (r.demos_added, r.max_demos_per_task) for r in strategy.expand(ctx)}

    settings, demos = round_with(limit=True)
    assert settings["limited_tasks"] == {"push-v3": 15} and demos == {
        "reach-v3": (20, 20),
        "push-v3": (15, 15),
    }
    settings, demos = round_with(limit=False)
    assert "limited_tasks" not in settings and demos == {"reach-v3": (20, 20), "push-v3": (20, 20)}
    # Resumed: the journaled limits hold, whatever the files would score now or the flag says now.
    for limit in (True, False):
        _, demos = round_with(limit, resumed={"limited_tasks": {"reach-v3": 4}, "target_successes": 10})
        assert demos == {"reach-v3": (4, 4), "push-v3": (20, 20)}
    _, demos = round_with(limit=True, resumed={"target_successes": 10})  # journaled without the flag
    assert demos == {"reach-v3": (20, 20), "push-v3": (20, 20)}
    # A task whose demonstrations cannot be scored (none yet) is not limited, and the note says why.
    three = BudgetRound(
        dict.fromkeys(("reach-v3", "push-v3", "pick-place-v3"), "F" * 100), budget=30, root=str(root)
    )
    with caplog.at_level("INFO"):
        assert disagreeing_task_caps(three, 30, 20) == {"push-v3": 10}
    assert (
        "note: pick-place-v3 is not limited: whether its demonstrations agree cannot be told (too few"
        in caplog.text
    )
    assert "note: reach-v3 is not limited" not in caplog.text
    # The share is rounded down: the limited tasks never get more than the budget between them.
    assert round_with(limit=True, budget=31)[0]["limited_tasks"] == {"push-v3": 15}
    # Through the round's journal: a round resumes with the flag either way, journaling what it started with
    # (also when the flag limited no task).
    for first, then in ((True, False), (False, True)):
        journal = RoundJournal(tmp_path / f"journal-{first}", 1)
        journal.start(round_with(first)[0])
        resumed_settings, _ = round_with(then, resumed=journal.of_type("start")[0])
        RoundJournal(tmp_path / f"journal-{first}", 1).start(resumed_settings)
    journal = RoundJournal(tmp_path / "nothing-limited", 1)
    journal.start({"strategy": "adademo", "target_successes": 10, "limited_tasks": {}})
    resumed_settings, demos = round_with(False, resumed=journal.of_type("start")[0])
    assert resumed_settings["limited_tasks"] == {} and demos == {"reach-v3": (20, 20), "push-v3": (20, 20)}


def test_task_only_refuses_plan_episodes_with_a_budget_that_would_ignore_them():
    from adademo_lerobot.strategies.task_only import TaskOnlyConfig

    config = TaskOnlyConfig(budget=[20], max_demos_per_task=[10], plan_episodes_per_task=5)
    with pytest.raises(AdaDemoError, match="plan_episodes_per_task sets the evaluations without a budget"):
        config.validate()
    TaskOnlyConfig(budget=[20], max_demos_per_task=[10]).validate()
    TaskOnlyConfig(target_successes=[5], max_demos_per_task=[10], plan_episodes_per_task=5).validate()


def test_knn_vote_is_the_failure_share_of_the_nearest_states():
    import numpy as np

    from adademo_lerobot.strategies.estimates import knn_failure_vote

    # Failures where x > 0, the second feature is noise on another scale, the third never varies.
    rng = np.random.default_rng(0)
    known = np.stack([np.linspace(-1, 1, 40), 100 * rng.standard_normal(40), np.ones(40)], axis=1)
    failed = (known[:, 0] > 0).astype(float)
    query = np.array([[0.9, 0.0, 1.0], [-0.9, 0.0, 1.0]])
    vote = knn_failure_vote(known[:, [0, 2]], failed, query[:, [0, 2]], 5)
    np.testing.assert_array_equal(vote, [1.0, 0.0])
    # Ties go to the earlier known state: the same on every machine and every resume.
    twins = np.array([[0.0], [0.0], [0.0], [1.0]])
    np.testing.assert_array_equal(
        knn_failure_vote(twins, np.array([1.0, 0.0, 0.0, 0.0]), np.zeros((1, 1)), 2), [0.5]
    )
    # No feature varies: every known state is as near as any, so the vote is the failure share of them all.
    same = np.ones((20, 3))
    np.testing.assert_allclose(
        knn_failure_vote(same, np.arange(20) % 2.0, np.ones((3, 3)), 5), [0.5, 0.5, 0.5]
    )


def test_limit_disagreeing_without_a_budget_is_refused():
    from adademo_lerobot.strategies.adademo import AdaDemoConfig

    config = AdaDemoConfig(target_successes=[5], max_demos_per_task=[10], limit_disagreeing=True)
    with pytest.raises(AdaDemoError, match="give --strategy.budget too"):
        config.validate()
    AdaDemoConfig(budget=[20], max_demos_per_task=[10], limit_disagreeing=True).validate()


def test_task_only_with_a_budget_evaluates_as_budgeted_but_demonstrates_from_fresh_states():
    outcomes = {"easy": "SSSSSSSSFSSSSSSSSSSSSSSSS" * 4, "hard": "FFFSFFFFFFFFFFFFFFFFFFFF" * 4}
    budgeted, ablation = BudgetRound(dict(outcomes), budget=10), BudgetRound(dict(outcomes), budget=10)
    b = {r.task: r for r in budgeted.strategy().expand(budgeted)}
    a = {r.task: r for r in ablation.strategy(at_failed_states=False, name="task_only").expand(ablation)}
    assert ablation.evaluated == budgeted.evaluated  # the same evaluations, in the same order
    assert {t: r.demos_added for t, r in a.items()} == {t: r.demos_added for t, r in b.items()}
    assert not any(ablation.collected.values())  # no demonstration at a failed state
    assert {t: len(v) for t, v in ablation.fresh.items()} == {t: r.demos_added for t, r in a.items()}
    assert all(r.strategy == "task_only" for r in a.values())


def test_rollout_cost_counts_rollouts_against_the_budget_and_closes_tasks_not_worth_evaluating():
    outcomes = {"solved": "S" * 100, "weak": "FSFFSFFSFFSFFSFF" * 6, "mid": "SFSSF" * 20}
    ctx = BudgetRound(outcomes, budget=30, batch_size=2, max_demos_per_task=8)
    records = {r.task: r for r in ctx.strategy(rollout_cost=1.0, failure_worth=3.0).expand(ctx)}
    cost = sum(r.demos_added + r.expert_failures + r.eval_episodes for r in records.values())
    assert cost == 30  # the whole budget: rollouts and demonstrations at failures, then fresh demonstrations
    # A task that keeps succeeding closes once c / u > W - 1 (u < 0.5): after two successes from Beta(1, 1),
    # and its posterior mean failure (1/4) is below 1 / W: no fresh demonstration either.
    assert records["solved"].eval_episodes <= 2 and records["solved"].demos_added == 0
    assert not ctx.fresh["solved"]
    assert records["weak"].demos_added > records["mid"].demos_added
    for (
        task,
        r,
    ) in records.items():  # demonstrations at failed states or fresh ones, every evaluation accounted
        assert all(ctx.outcomes[task][ctx._position[task][s]] == "F" for s in ctx.collected[task])
        assert r.eval_episodes == r.successes + r.failures
        assert (
            r.demos_added
            == len(ctx.collected[task]) + len(ctx.fresh[task])
            == r.failures + len(ctx.fresh[task])
        )
        assert r.extra["fresh_demos"] == len(ctx.fresh[task])
        if ctx.fresh[task]:  # only once evaluating stopped paying: c / u > W - 1
            assert r.extra["closed_as_not_worth"]
    assert len(ctx.fresh["mid"]) == 3  # principle A alone for what the rollouts no longer pay for
    # With room left under CAP only: what no task is worth stays unspent.
    roomy = BudgetRound(dict(outcomes), budget=40, batch_size=2, max_demos_per_task=8)
    records = {r.task: r for r in roomy.strategy(rollout_cost=1.0).expand(roomy)}
    assert {t: r.demos_added for t, r in records.items()} == {"solved": 0, "weak": 8, "mid": 8}
    assert records["solved"].extra["round_cost"] == 34
    # Rollouts free: the budget goes to demonstrations only, and every task stays worth evaluating.
    free = BudgetRound(dict(outcomes), budget=20, batch_size=2)
    records = {r.task: r for r in free.strategy(rollout_cost=0.0).expand(free)}
    assert sum(r.demos_added for r in records.values()) == 20


def test_probing_keeps_a_task_that_succeeded_by_luck_from_getting_nothing():
    """Paying for rollouts, two lucky successes close a task at 40 % failure (Beta(1, 1) -> mean 1/4 < 1/W):
    with --strategy.probe_unsure it gets single rollouts until its 80th percentile falls under 1/W or it shows
    failures, which are answered at once; a truly solved task costs one probe more and gets nothing."""
    outcomes = {"solved": "S" * 100, "lucky": "SS" + "FSFSFFSFSF" * 10, "weak": "FSFFSFFSFFSFFSFF" * 6}

    def run(**options):
        ctx = BudgetRound(dict(outcomes), budget=30, batch_size=2, max_demos_per_task=8)
        records = {r.task: r for r in ctx.strategy(rollout_cost=1.0, **options).expand(ctx)}
        assert sum(r.demos_added + r.expert_failures + r.eval_episodes for r in records.values()) <= 30
        return ctx, records

    ctx, plain = run()
    assert plain["lucky"].eval_episodes == 2 and plain["lucky"].demos_added == 0
    ctx, probed = run(probe_unsure=True)
    assert probed["lucky"].extra["probes"] >= 1 and probed["lucky"].failures >= 1
    assert probed["lucky"].demos_added >= probed["lucky"].failures
    # solved: Beta(1, k + 1)'s 80th percentile, 1 - 0.2 ** (1 / (k + 1)), is under 1/3 from k = 3 successes on.
    assert probed["solved"].eval_episodes == 3 and probed["solved"].demos_added == 0
    assert probed["solved"].extra["probes"] == 1 and "probes" not in plain["solved"].extra
    for task, r in probed.items():  # every demonstration at a failed state or a fresh one, as without probes
        assert all(ctx.outcomes[task][ctx._position[task][s]] == "F" for s in ctx.collected[task])
        assert r.demos_added == len(ctx.collected[task]) + len(ctx.fresh[task])


def test_split_episodes_shares_the_round_by_expected_failure_instead_of_feeding_the_weakest_task():
    """Greedy evaluation (the task with the highest optimistic failure rate first) gives almost the whole round to
    the weakest task; --strategy.split_episodes splits the budget, rollouts included, by posterior mean failure
    rate, so every task that fails gets a share and the weakest the largest; a solved task still closes."""
    outcomes = {
        "solved": "S" * 100,
        "weak": "FSFFSFFSFFSFFSFF" * 6,
        "mid": "SFSSF" * 20,
        "mid2": "SSFSF" * 20,
    }

    def run(**options):
        ctx = BudgetRound(dict(outcomes), budget=30, batch_size=4, max_demos_per_task=12)
        records = {
            r.task: r for r in ctx.strategy(rollout_cost=1.0, probe_unsure=True, **options).expand(ctx)
        }
        spent = {t: r.demos_added + r.expert_failures + r.eval_episodes for t, r in records.items()}
        assert sum(spent.values()) == 30  # the whole budget, never more
        for task, r in records.items():  # each demonstration at a failed state or a fresh one
            assert all(ctx.outcomes[task][ctx._position[task][s]] == "F" for s in ctx.collected[task])
            assert r.demos_added == len(ctx.collected[task]) + len(ctx.fresh[task])
            assert r.eval_episodes == r.successes + r.failures
        return records, spent

    greedy, greedy_spent = run()
    assert greedy_spent["weak"] >= 20 and greedy["mid"].demos_added == greedy["mid2"].demos_added == 0
    split, spent = run(split_episodes=True)
    assert split["mid"].demos_added >= 2 and split["mid2"].demos_added >= 2
    assert spent["weak"] > max(spent["mid"], spent["mid2"]) > spent["solved"]
    assert split["solved"].demos_added == 0 and split["solved"].eval_episodes == 3  # closed as with greedy
    # Evaluating pays on the weakest task: every one of its demonstrations is at a failure.
    assert split["weak"].demos_added == split["weak"].failures


def test_a_correction_is_paid_by_the_rollout_it_continues_so_evaluating_pays_sooner():
    """With --demo_start=takeover a failure's answer continues its rollout in the same scene (one episode,
    `core/costs.py`): the round pays its budget in episodes, the weakest task gets more of its failed states, and a
    task failing 40 % of the time is worth evaluating (its corrections cost nothing more: u >= c / W, not
    c / (W - 1)) instead of getting fresh demonstrations; unless the expert fails from its takeover states, each
    then a demonstration from the initial state that costs one more episode, as without corrections."""
    outcomes = {
        "solved": "S" * 100,
        "weak": "FSFFSFFSFFSFFSFF" * 6,
        "mid": "SFSSF" * 20,
        "mid_x": "SFSSF" * 20,
    }

    def run(corrects_failures: bool):
        ctx = BudgetRound(
            dict(outcomes),
            budget=40,
            batch_size=4,
            max_demos_per_task=12,
            corrects_failures=corrects_failures,
            expert_fails_on={"mid_x": set(range(100))} if corrects_failures else {},
        )
        strategy = ctx.strategy(rollout_cost=1.0, probe_unsure=True, split_episodes=True)
        records = {r.task: r for r in strategy.expand(ctx)}
        episodes = sum(
            r.demos_added - r.corrections + r.expert_failures + r.eval_episodes for r in records.values()
        )
        assert episodes == 40 and all(r.extra["round_cost"] == 40 for r in records.values())
        for task, r in records.items():
            assert all(ctx.outcomes[task][ctx._position[task][s]] == "F" for s in ctx.collected[task])
            assert r.demos_added == len(ctx.collected[task]) + len(ctx.fresh[task])
        return records, ctx.fresh

    separate, fresh = run(corrects_failures=False)
    continued, fresh_continued = run(corrects_failures=True)
    assert sum(r.corrections for r in separate.values()) == 0
    assert continued["weak"].corrections > separate["weak"].demos_added  # more of its failed states
    assert fresh["mid"] and not fresh_continued["mid"]  # evaluated instead: every demonstration a correction
    assert continued["mid"].corrections == continued["mid"].demos_added > 0
    assert continued["mid"].eval_episodes > separate["mid"].eval_episodes
    assert continued["mid_x"].takeover_failures >= 1 and fresh_continued["mid_x"]  # back to fresh states
    assert continued["mid_x"].corrections == 0
    assert continued["solved"].demos_added == separate["solved"].demos_added == 0


def test_optimism_sets_how_many_straight_successes_close_a_task():
    """--strategy.optimism is the posterior quantile of the failure rate that keeps a task open: at 0.8 three
    straight successes close it (Beta(1, 4)'s 80th percentile is under 1/3), at 0.9 five; a task at 60 % success
    that starts with three successes by luck then shows its failures and gets demonstrations."""
    outcomes = {"solved": "S" * 100, "lucky": "SSS" + "FSFSF" * 20}
    for optimism, solved_rollouts in ((0.8, 3), (0.9, 5)):
        ctx = BudgetRound(dict(outcomes), budget=30, batch_size=2, max_demos_per_task=8)
        strategy = ctx.strategy(rollout_cost=1.0, probe_unsure=True, split_episodes=True, optimism=optimism)
        records = {r.task: r for r in strategy.expand(ctx)}
        assert records["solved"].eval_episodes == solved_rollouts and records["solved"].demos_added == 0
        if optimism == 0.8:
            assert records["lucky"].eval_episodes == 3 and records["lucky"].demos_added == 0
        else:
            assert records["lucky"].failures >= 1 and records["lucky"].demos_added >= 1
