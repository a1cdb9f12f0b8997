"""Dataclass configs shared by the commands (parsed by draccus, LeRobot-style dotted flags)."""

from __future__ import annotations

from dataclasses import dataclass, field

from adademo_lerobot.collectors.base import CollectorConfig, ScriptedCollectorConfig
from adademo_lerobot.suites.base import SuiteConfig
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


@dataclass
class DatasetArgs:
    repo_id: str = "local/adademo"
    # Folder of the LeRobot dataset (required).
    root: str | None = None


def default_suite() -> SuiteConfig:
    return MetaWorldSuiteConfig()


def default_collector() -> CollectorConfig:
    return ScriptedCollectorConfig()


@dataclass
class CollectConfig:
    suite: SuiteConfig = field(default_factory=default_suite)
    collector: CollectorConfig = field(default_factory=default_collector)
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    # Demonstrations per task (a target: rerunning with --resume=true completes an interrupted collection).
    episodes_per_task: int = 10
    seed: int = 0
    resume: bool = False
    # Episodes buffered in memory between dataset commits (a kill loses at most these).
    commit_every: int = 10
