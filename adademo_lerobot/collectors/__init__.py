from adademo_lerobot.collectors.base import (
    CollectionResult,
    CollectorConfig,
    Demonstration,
    ExpertCollector,
    make_collector,
)
from adademo_lerobot.collectors.policy import PolicyCollectorConfig  # registers `--collector.type=policy`

__all__ = ["CollectionResult", "CollectorConfig", "Demonstration", "ExpertCollector", "PolicyCollectorConfig",
           "make_collector"]
