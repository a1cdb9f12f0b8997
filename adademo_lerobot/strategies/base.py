"""What every expansion strategy is configured by (`StrategyConfig`), gets (`RoundContext`, in
`strategies.round_context`) and provides (`ExpansionStrategy`).

A strategy is a draccus `ChoiceRegistry` config (`--strategy.type=adademo|budgeted|uniform|task_only`, as suites and
collectors are) with its own fields, checks and description; `build(i)` gives round i's strategy, whose one entry
point `expand(ctx)` runs the round. Per-round settings (E_i, CAP_i, N_i, B_i) are `PerRound` values: one value for
every round, or a list whose last value repeats.

The context owns the side effects a round needs, each journaled so an interrupted round resumes exactly.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import draccus

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError

if TYPE_CHECKING:
    from adademo_lerobot.strategies.round_context import RoundContext

# E when none is given (the paper's runs use 5 to 20).
DEFAULT_TARGET_SUCCESSES = 10


class PerRound(tuple):
    """A setting per expansion round: `5` for every round, or `[5, 10, 20]` (the last value repeats)."""

    def at(self, round_in_run: int) -> int | None:
        """Round i's value (i from 1); None when unset."""
        return self[min(round_in_run, len(self)) - 1] if self else None


def _decode_per_round(raw: Any, path) -> PerRound:
    values = raw if isinstance(raw, list | tuple) else ([] if raw is None else [raw])
    try:
        return PerRound(int(v) for v in values)
    except (TypeError, ValueError):
        raise draccus.utils.DecodingError(
            path, f"expected a number or a list of numbers, got {raw!r}"
        ) from None


draccus.decode.register(PerRound, _decode_per_round)
draccus.encode.register(PerRound, list)


def per_round(*values: int) -> PerRound:
    """A `PerRound` default for a dataclass field."""
    return field(default_factory=lambda: PerRound(values))


def planned_demos(target_successes: int, success_rate: float, cap: int) -> int:
    """The paper's N_k = E / SR_k - E, capped at CAP (SR_k = 0 gets CAP): the one formula every command uses.
    The rate is a ratio of counts, so E / SR_k - E is a rational number; the tolerance keeps float rounding from
    adding a demonstration (E = 2, SR = 2/49: 47, not 48)."""
    if success_rate <= 0:
        return cap
    return min(cap, max(0, math.ceil(target_successes / success_rate - target_successes - 1e-9)))


def default_eval_bound(target_successes: int | None, cap: int) -> int:
    """Evaluation episodes per task and round when none is given: 2 x (E + CAP), so a task whose expert keeps
    failing still ends."""
    return 2 * ((target_successes or DEFAULT_TARGET_SUCCESSES) + cap)


def split_evenly(budget: int, tasks: list[str]) -> dict[str, int]:
    """Uniform's demos per task for a budget: B // K each, the first B mod K tasks one more (sums to B)."""
    base, extra = divmod(budget, len(tasks))
    return {t: base + (i < extra) for i, t in enumerate(tasks)}


def check_per_round(name: str, values: PerRound, required: bool = False) -> None:
    if (required and not values) or any(v < 1 for v in values):
        raise AdaDemoError(
            f"--strategy.{name} needs one value >= 1, or one per round ([v1,v2,...]), got {list(values) or 'none'}"
        )


@dataclass
class StrategyConfig(draccus.ChoiceRegistry, abc.ABC):
    """Which expansion strategy adds a round's demonstrations, with its own settings (`--strategy.type=NAME
    --strategy.FIELD=...`). Each registers itself and builds its rounds' strategies."""

    # One line, for the dataset card (`adademo-push`: `loop/dataset_card.source_description`).
    description: ClassVar[str]
    needs_policy: ClassVar[bool]  # it evaluates the policy
    collects_at_failed_states: ClassVar[bool]  # its demonstrations answer failed evaluations (principle B)

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    @classmethod
    def default_choice_name(cls) -> str | None:
        return "adademo"

    def validate(self) -> None:
        """Refuse bad settings in one line (before anything is written)."""

    def check_one_round(self, command: str = "adademo-expand") -> None:
        """`command` runs one round: refuse a list of several per-round values."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, PerRound) and len(value) > 1:
                raise AdaDemoError(
                    f"--strategy.{f.name}={list(value)}: {command} runs one round, give one value "
                    "(a list per round is for adademo-run)"
                )

    def answers_failures_only(self) -> bool:
        """Every demonstration of its rounds answers a failed policy episode (`algorithm.InnerLoop` is all its
        rounds ask for), so a person at a robot can run it (`adademo-record`). Strategies that also demonstrate
        from fresh initial states need a simulated round (`RoundContext`)."""
        return self.collects_at_failed_states

    def needs_a_simulator(self) -> str | None:
        """Why a person at a robot cannot run its rounds, None if they can (`adademo-record`): a round a person runs
        asks only for policy episodes and demonstrations, each from a failed episode's start or from a new scene
        (the `algorithm.InnerLoop` part of a round), never for initial states sampled by a simulator."""
        if self.answers_failures_only():
            return None
        return f"--strategy.type={self.type} takes demonstrations from fresh initial states it samples itself"

    @classmethod
    def running_with_a_person(cls) -> list[str]:
        """The registered strategies a person at a robot can run with their default settings."""
        return [
            name for name, choice in cls.get_known_choices().items() if choice().needs_a_simulator() is None
        ]

    def can_plan(self) -> bool:
        """Its rounds predict each task's demonstrations from the success rate alone (N_k = E/SR_k - E, capped):
        it builds `PlanningStrategy` rounds, which `adademo-expand --plan_only` prices without collecting."""
        return False

    @classmethod
    def planning(cls) -> list[str]:
        """The registered strategies whose default settings can plan."""
        return [name for name, choice in cls.get_known_choices().items() if choice().can_plan()]

    @abc.abstractmethod
    def build(self, round_in_run: int) -> ExpansionStrategy:
        """The strategy of the run's round `round_in_run` (from 1), with that round's values."""

    def to_dict(self) -> dict[str, Any]:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {"type": self.type, **{k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}}

    def summary(self) -> str:
        """`type (field=value, ...)` of the settings that differ from the defaults: how reports name it."""
        defaults = type(self)().to_dict()
        parts = [f"{k}={v}" for k, v in self.to_dict().items() if k != "type" and v != defaults[k]]
        return f"{self.type} ({', '.join(parts)})" if parts else self.type


class ExpansionStrategy(Protocol):
    """One round's strategy: `expand(ctx)` adds the round's demonstrations and accounts for them per task. A
    strategy whose config `answers_failures_only()` uses only the `algorithm.InnerLoop` part of its context, so it
    also runs with a person at a robot (`record.PersonRound`)."""

    name: str
    commits_by_task: bool  # demos are committed task by task in suite order (else in the order they arrive)

    def start(self, ctx: RoundContext, resumed: dict | None) -> dict:
        """Fix the round's decisions before it runs (e.g. E from a budget; a resumed round keeps the ones it
        journaled, `resumed`) and return the settings to journal."""

    def expand(self, ctx: RoundContext) -> list[TaskRoundRecord]:
        """The round: one record per task of the suite, in suite order."""


class PlanningStrategy(ExpansionStrategy, Protocol):
    """A round that predicts each task's demonstrations from its success rate: N_k = E/SR_k - E, capped at CAP
    (built by a config whose `can_plan()` is true)."""

    target_successes: int  # E, once `start` has picked it
    cap: int

    def task_cap(self, task: str) -> int:
        """The task's CAP this round, once `start` has fixed it (`cap`, or less: `limit_disagreeing`)."""
        ...
