"""`--collector.type=smoothed`: the suite's scripted expert with its actions smoothed by an exponential moving
average (`--collector.smoothing=s`: each action is s times the previous one plus 1 - s times the scripted
expert's), for demonstrations without the scripted experts' jerks. It wraps a built-in expert's action function and
keeps what every simulated expert gets: retries, the success check, recording, takeover."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from adademo_lerobot.collectors.base import CollectorConfig, SimulatedExpertCollector
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import TaskSuite


@CollectorConfig.register_subclass("smoothed")
@dataclass
class SmoothedCollectorConfig(ScriptedCollectorConfig):
    """The suite's scripted expert with smoothed actions (a kind of scripted expert: where a suite has none, the
    message that lists the other experts leaves it out)."""

    # The previous action's weight in each new one: 0 is the scripted expert itself.
    smoothing: float = 0.5

    def build(self, suite: TaskSuite) -> SmoothedExpert:
        if not 0 <= self.smoothing < 1:
            raise AdaDemoError(
                f"--collector.smoothing={self.smoothing}: give the previous action's weight in [0, 1) "
                "(0: the scripted expert unchanged)"
            )
        return SmoothedExpert(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        return f"smoothed-{ScriptedCollectorConfig().expert_name(suite)}"  # recorded in adademo/collector

    def expert_class(self, suite: TaskSuite) -> type:
        return SmoothedExpert


class SmoothedExpert(SimulatedExpertCollector):
    acts_mid_episode = True  # a fresh smoother starts at the scripted expert's own action, from any state

    def __init__(self, suite: TaskSuite, config: SmoothedCollectorConfig):
        super().__init__(suite, config)
        self.name = config.expert_name(suite)
        # A suite without a scripted expert is refused here, in one line.
        self.scripted = ScriptedCollectorConfig().build(suite)

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        """A new smoother for each attempt: its first action is the scripted expert's."""
        scripted, weight = self.scripted.expert_for(task), self.config.smoothing
        previous = None

        def act(observation: dict) -> np.ndarray:
            nonlocal previous
            action = np.asarray(scripted(observation), np.float64)
            previous = action if previous is None else weight * previous + (1 - weight) * action
            return previous

        return act
