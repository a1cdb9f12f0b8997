"""Task suites: MetaWorld (default, CPU), Fetch and Adroit (gymnasium-robotics), and any LeRobot simulation env
(`lerobot_env`). Importing this package registers their configs (`--suite.type=...`); each builds its own suite."""

from __future__ import annotations

import dataclasses
from typing import Any

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.adroit import AdroitSuiteConfig
from adademo_lerobot.suites.base import SuiteConfig, TaskSuite
from adademo_lerobot.suites.fetch import FetchSuiteConfig
from adademo_lerobot.suites.lerobot_env import LeRobotEnvSuiteConfig
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def make_suite(config: SuiteConfig) -> TaskSuite:
    return config.build()


def suite_config_from_dict(data: dict[str, Any]) -> SuiteConfig:
    """A config from its stored form (`meta/adademo/suite.json`); unknown keys are ignored."""
    data = dict(data)
    kind = data.pop("type", "metaworld")
    try:
        cls = SuiteConfig.get_choice_class(kind)
    except KeyError:
        raise AdaDemoError(
            f"unknown suite type {kind!r}; known: {sorted(SuiteConfig.get_known_choices())}"
        ) from None
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in data.items() if k in names})


__all__ = [
    "AdroitSuiteConfig",
    "FetchSuiteConfig",
    "LeRobotEnvSuiteConfig",
    "MetaWorldSuiteConfig",
    "SuiteConfig",
    "TaskSuite",
    "make_suite",
    "suite_config_from_dict",
]
