"""`--collector.type=callable --collector.entry=package.module:factory`: a controller shipped with an env's package
as the expert, with the retries, success check and recording every simulated expert gets.

`factory(env)` is called once per attempt with the task's env as its package made it (a suite's own env for our
built-in suites) and returns the controller of that attempt: a callable from the env's own observation to an
action (it may keep state: a fresh one starts every attempt). The first call is checked before anything is written:
an entry that cannot be imported, or an action of the wrong shape, is one `error:` line.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from adademo_lerobot.collectors.base import CollectorConfig, ExpertCollector, SimulatedExpertCollector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import TaskSuite


@CollectorConfig.register_subclass("callable")
@dataclass
class CallableCollectorConfig(CollectorConfig):
    """A controller from an env's package: `package.module:factory`, factory(env) -> (observation -> action)."""

    entry: str | None = None
    # For the messages that list the experts a suite can use.
    expert_hint: ClassVar[str] = (
        "your own expert function, --collector.entry=package.module:factory: docs/lerobot-env.md"
    )

    def build(self, suite: TaskSuite) -> ExpertCollector:
        return CallableExpert(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        return f"callable:{self.entry}"

    def expert_class(self, suite: TaskSuite) -> type:
        return CallableExpert

    def validate(self, suite: TaskSuite) -> None:
        """Import the entry and ask one controller for one action on each task (nothing is recorded)."""
        expert = self.build(suite)
        try:
            for task in suite.tasks:
                env = expert._env(task)
                obs, _ = env.reset(options={"initial_state": suite.sample_initial_state(task, 0)})
                expert.expert_for(task)(obs)
        finally:
            expert.close()


def load_entry(entry: str | None) -> Callable:
    if not entry or ":" not in entry:
        raise AdaDemoError(
            f"--collector.entry={entry!r}: give the controller factory as package.module:factory "
            "(--collector.type=callable)"
        )
    module, name = entry.split(":", 1)
    try:
        factory = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as err:
        raise AdaDemoError(
            f"--collector.entry={entry}: cannot import it ({type(err).__name__}: {err})"
        ) from None
    if not callable(factory):
        raise AdaDemoError(f"--collector.entry={entry} is not callable")
    return factory


class CallableExpert(SimulatedExpertCollector):
    name = "callable"
    acts_mid_episode = False  # a package's controller may keep phases that assume the episode's start

    def __init__(self, suite: TaskSuite, config: CallableCollectorConfig):
        super().__init__(suite, config)
        self.entry = config.entry
        self.factory = load_entry(config.entry)

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        env = self._env(task).unwrapped
        package_env = getattr(env, "_raw", env)  # the env as its package made it
        controller = self.factory(package_env)
        shape = (self.suite.action_dim,)

        def act(observation: dict) -> np.ndarray:
            own = getattr(env, "raw_observation", None) or observation  # the env's own observation
            action = np.asarray(controller(own), dtype=np.float64)
            if action.shape != shape:
                raise AdaDemoError(
                    f"the expert {self.entry} returned an action of shape {action.shape}; the env takes {shape}"
                )
            return action

        return act
