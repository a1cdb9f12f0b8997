"""Expansion strategies, a `--strategy.type` each: AdaDemo (A+B), the budgeted AdaDemo, the Uniform baseline and
ablation A (task_only). Importing this package registers them."""

from adademo_lerobot.strategies.adademo import AdaDemoConfig
from adademo_lerobot.strategies.base import (
    ExpansionStrategy,
    PerRound,
    StrategyConfig,
    planned_demos,
)
from adademo_lerobot.strategies.budgeted import BudgetedConfig
from adademo_lerobot.strategies.round_context import RoundContext
from adademo_lerobot.strategies.task_only import TaskOnlyConfig
from adademo_lerobot.strategies.uniform import UniformConfig


def default_strategy() -> StrategyConfig:
    return AdaDemoConfig()


__all__ = [
    "AdaDemoConfig",
    "BudgetedConfig",
    "ExpansionStrategy",
    "PerRound",
    "RoundContext",
    "StrategyConfig",
    "TaskOnlyConfig",
    "UniformConfig",
    "default_strategy",
    "planned_demos",
]
