from adademo_lerobot.collectors.base import (
    CollectionResult,
    CollectorConfig,
    Demonstration,
    ExpertCollector,
    make_collector,
)

__all__ = ["CollectionResult", "CollectorConfig", "Demonstration", "ExpertCollector", "make_collector"]
