"""`--collector.type=scripted` (the default): each suite's built-in scripted expert."""

from __future__ import annotations

from dataclasses import dataclass

from adademo_lerobot.collectors.adroit_scripted import AdroitScriptedExpert
from adademo_lerobot.collectors.base import CollectorConfig, ExpertCollector
from adademo_lerobot.collectors.fetch_scripted import FetchScriptedExpert
from adademo_lerobot.collectors.metaworld_scripted import MetaWorldScriptedExpert
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import TaskSuite

SCRIPTED_EXPERTS = {
    "metaworld": MetaWorldScriptedExpert,
    "fetch": FetchScriptedExpert,
    "adroit": AdroitScriptedExpert,
}


@CollectorConfig.register_subclass("scripted")
@dataclass
class ScriptedCollectorConfig(CollectorConfig):
    """The suite's built-in scripted experts (MetaWorld: `metaworld.policies`; Fetch: `fetch_scripted`; Adroit:
    `adroit_scripted`)."""

    def build(self, suite: TaskSuite) -> ExpertCollector:
        return self.expert_class(suite)(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        return self.expert_class(suite).name

    def expert_class(self, suite: TaskSuite) -> type:
        if suite.name not in SCRIPTED_EXPERTS:
            # Every other registered expert type that can act in this suite, so that a new one is named here too;
            # not those built on the scripted experts (a plugin's), which need one as well.
            others = [
                f"--collector.type={name}"
                + (f" ({cls.expert_hint})" if getattr(cls, "expert_hint", "") else "")
                for name, cls in sorted(CollectorConfig.get_known_choices().items())
                if not issubclass(cls, ScriptedCollectorConfig) and cls.serves(suite)
            ]
            raise AdaDemoError(
                f"no scripted expert for suite {suite.name!r} (only for {', '.join(SCRIPTED_EXPERTS)}); use "
                f"{' or '.join(others)}; a dataset keeps its suite but not its expert, so name the expert with "
                "--collector.* (or collector: in the recipe)"
            )
        return SCRIPTED_EXPERTS[suite.name]
