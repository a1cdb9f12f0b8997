"""Expert collectors. Importing this package registers `--collector.type=scripted|policy|callable|planner`."""

from adademo_lerobot.collectors.base import CollectorConfig, ExpertCollector, SimulatedExpertCollector
from adademo_lerobot.collectors.callable import CallableCollectorConfig
from adademo_lerobot.collectors.checkpoint import PolicyCollectorConfig
from adademo_lerobot.collectors.planner import PlannerCollectorConfig
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.suites.base import TaskSuite


def make_collector(config: CollectorConfig, suite: TaskSuite) -> ExpertCollector:
    return config.build(suite)


__all__ = [
    "CallableCollectorConfig",
    "CollectorConfig",
    "ExpertCollector",
    "PlannerCollectorConfig",
    "PolicyCollectorConfig",
    "ScriptedCollectorConfig",
    "SimulatedExpertCollector",
    "make_collector",
]
