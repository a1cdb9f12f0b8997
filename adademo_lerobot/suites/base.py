"""The task-suite protocol every benchmark family implements.

A suite knows its task list (whose order defines the task one-hot), builds one env per task, samples an
initial state from a seed and restores any recorded initial state exactly. Envs are plain gymnasium envs with
dict observations in LeRobot's env convention (`agent_pos`, `environment_state`, optional `pixels`), so
LeRobot's own `preprocess_observation` and `rollout` work on them unchanged.
"""

from __future__ import annotations

import abc
import dataclasses
import difflib
import json
import zlib
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import draccus
import gymnasium as gym
import numpy as np

from adademo_lerobot.errors import AdaDemoError

OBS_TYPES = ("state", "pixels_state")


@dataclass
class SuiteConfig(draccus.ChoiceRegistry, abc.ABC):
    """Which benchmark family, which tasks, which observations. Stored with every dataset."""

    # Comma-separated task names (or a group name the suite knows, e.g. `mt10`).
    tasks: str = ""
    # `state` (default, CPU-friendly) or `pixels_state` (adds a rendered camera image).
    obs_type: str = "state"
    image_size: int = 128
    # Episode step limit for evaluation and expert collection.
    max_episode_steps: int = 300

    @property
    def type(self) -> str:
        return self.get_choice_name(self.__class__)

    @classmethod
    def default_choice_name(cls) -> str | None:
        return "metaworld"

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.type, **dataclasses.asdict(self)}

    @staticmethod
    def from_dict(data: dict[str, Any]) -> SuiteConfig:
        import adademo_lerobot.suites  # noqa: F401  (registers the built-in suites)

        data = dict(data)
        kind = data.pop("type")
        try:
            cls = SuiteConfig.get_choice_class(kind)
        except KeyError:
            raise AdaDemoError(f"unknown suite type {kind!r}; known: {sorted(SuiteConfig.get_known_choices())}")
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)


@runtime_checkable
class TaskSuite(Protocol):
    """One benchmark family: tasks, envs, exact initial states, success and task conditioning."""

    config: SuiteConfig
    name: str

    @property
    def tasks(self) -> list[str]:
        """Task names in one-hot order."""

    def make_env(self, task: str) -> gym.Env:
        """A gymnasium env for `task` whose `reset(options={"initial_state": s})` restores `s` exactly,
        whose `reset(seed=k)` starts from `sample_initial_state(task, k)`, and whose `info["is_success"]`
        reports success."""

    def sample_initial_state(self, task: str, seed: int) -> np.ndarray:
        """A fresh initial state of `task`, a deterministic function of `seed` (float64 vector)."""

    def task_onehot(self, task: str) -> np.ndarray:
        """The task-conditioning vector: a one-hot over `tasks`."""

    def task_description(self, task: str) -> str:
        """A human-readable description of the task."""


def onehot(tasks: list[str], task: str) -> np.ndarray:
    vec = np.zeros(len(tasks), dtype=np.float64)
    vec[tasks.index(task)] = 1.0
    return vec


def split_task_list(tasks: str) -> list[str]:
    return [t.strip() for t in tasks.split(",") if t.strip()]


def check_task_names(requested: list[str], known: list[str], suite: str) -> None:
    """Fail with the closest valid names when a task is unknown."""
    if not requested:
        raise AdaDemoError(f"empty task list for suite {suite!r}: pass --suite.tasks=task1,task2")
    for task in requested:
        if task not in known:
            close = difflib.get_close_matches(task, known, n=3, cutoff=0.4)
            hint = f"; did you mean {', '.join(close)}?" if close else f"; valid tasks: {', '.join(known)}"
            raise AdaDemoError(f"unknown {suite} task {task!r}{hint}")
    duplicates = sorted({t for t in requested if requested.count(t) > 1})
    if duplicates:
        raise AdaDemoError(f"task listed twice in --suite.tasks: {', '.join(duplicates)}")


def check_obs_type(obs_type: str) -> None:
    if obs_type not in OBS_TYPES:
        raise AdaDemoError(f"unknown --suite.obs_type={obs_type!r}; choose one of {', '.join(OBS_TYPES)}")


def derive_seed(*keys: int | str) -> int:
    """A stable 63-bit seed from a tuple of ints and strings (strings hashed with CRC32, stable across runs)."""
    ints = [k if isinstance(k, int) else zlib.crc32(k.encode()) for k in keys]
    high, low = np.random.SeedSequence(ints).generate_state(2, dtype=np.uint32)
    return (int(high) << 31) | (int(low) >> 1)


def make_suite(config: SuiteConfig) -> TaskSuite:
    """Build the suite a config names (imports the family lazily: each pulls a different simulator)."""
    if config.type == "metaworld":
        from adademo_lerobot.suites.metaworld import MetaWorldSuite

        return MetaWorldSuite(config)
    elif config.type == "fetch":
        from adademo_lerobot.suites.fetch import FetchSuite

        return FetchSuite(config)
    elif config.type == "adroit":
        from adademo_lerobot.suites.adroit import AdroitSuite

        return AdroitSuite(config)
    raise AdaDemoError(f"no suite implementation for type {config.type!r}")
