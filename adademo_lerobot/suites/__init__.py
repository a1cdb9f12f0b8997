"""Task suites. Importing this package registers the built-in suite configs with draccus."""

from adademo_lerobot.suites.adroit import AdroitSuiteConfig
from adademo_lerobot.suites.base import SuiteConfig, TaskSuite, make_suite
from adademo_lerobot.suites.fetch import FetchSuiteConfig
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

__all__ = ["AdroitSuiteConfig", "FetchSuiteConfig", "MetaWorldSuiteConfig", "SuiteConfig", "TaskSuite", "make_suite"]
