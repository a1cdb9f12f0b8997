"""Expansion strategies: AdaDemo (A+B), the Uniform baseline, ablation A (task_only) and the budgeted AdaDemo."""

from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.strategies.adademo import AdaDemoStrategy
from adademo_lerobot.strategies.base import ExpansionStrategy, RoundContext, planned_demos
from adademo_lerobot.strategies.budgeted import BudgetedStrategy
from adademo_lerobot.strategies.task_only import TaskOnlyStrategy
from adademo_lerobot.strategies.uniform import UniformStrategy

STRATEGY_CLASSES: dict[str, type] = {
    cls.name: cls for cls in (AdaDemoStrategy, BudgetedStrategy, UniformStrategy, TaskOnlyStrategy)
}
STRATEGIES = tuple(STRATEGY_CLASSES)


def make_strategy(name: str) -> ExpansionStrategy:
    if name not in STRATEGY_CLASSES:
        raise AdaDemoError(f"unknown --strategy={name!r}; choose one of {', '.join(STRATEGIES)}")
    return STRATEGY_CLASSES[name]()


__all__ = ["STRATEGIES", "ExpansionStrategy", "RoundContext", "make_strategy", "planned_demos"]
