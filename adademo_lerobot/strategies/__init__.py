"""Expansion strategies: AdaDemo (A+B), the Uniform baseline and ablation A (task_only)."""

from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.strategies.base import ExpansionStrategy, RoundContext, planned_demos

STRATEGIES = ("adademo", "uniform", "task_only")


def make_strategy(name: str) -> ExpansionStrategy:
    if name == "adademo":
        from adademo_lerobot.strategies.adademo import AdaDemoStrategy

        return AdaDemoStrategy()
    if name == "uniform":
        from adademo_lerobot.strategies.uniform import UniformStrategy

        return UniformStrategy()
    if name == "task_only":
        from adademo_lerobot.strategies.task_only import TaskOnlyStrategy

        return TaskOnlyStrategy()
    raise AdaDemoError(f"unknown --strategy={name!r}; choose one of {', '.join(STRATEGIES)}")


__all__ = ["STRATEGIES", "ExpansionStrategy", "RoundContext", "make_strategy", "planned_demos"]
