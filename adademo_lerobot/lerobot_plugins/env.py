"""Our suites as a LeRobot env type, so stock `lerobot-eval` evaluates our checkpoints on our tasks:

    lerobot-eval --policy.path=CKPT --env.type=adademo --env.dataset_root=DATASET --env.task=reach-v3 \\
        --eval.n_episodes=10 --eval.batch_size=10

LeRobot imports this module by itself (the installed `lerobot_env_adademo` plugin distribution), so no
`--env.discover_packages_path` is needed.

`--env.dataset_root` rebuilds the suite from a dataset's `meta/adademo/suite.json` (or give
`--env.suite_type/--env.tasks/--env.obs_type`). One task per invocation: LeRobot's env config names one task.
`reset(seed=k)` starts from the suite's initial state for seed k, so lerobot-eval's seeds are reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.metadata import load_suite_config
from adademo_lerobot.suites import make_suite, suite_config_from_dict

GYM_ID = "adademo/SuiteTask-v0"
# The env's observation keys (LeRobot's env convention) for each dataset feature.
ENV_KEYS = {
    "observation.state": "agent_pos",
    "observation.environment_state": "environment_state",
    "action": "action",
}
FEATURE_TYPES = {
    "agent_pos": FeatureType.STATE,
    "environment_state": FeatureType.ENV,
    "action": FeatureType.ACTION,
}


def make_suite_task_env(suite: dict, task: str, **_):
    return make_suite(suite_config_from_dict(suite)).make_env(task, terminate_on_success=True)


if GYM_ID not in gym.registry:
    gym.register(GYM_ID, entry_point=make_suite_task_env)


@EnvConfig.register_subclass("adademo")
@dataclass
class AdaDemoEnv(EnvConfig):
    task: str | None = None
    dataset_root: str | None = None
    suite_type: str = "metaworld"
    tasks: str = ""
    obs_type: str = "state"
    image_size: int = 128
    # Default: the suite's own step limit.
    max_episode_steps: int | None = None
    fps: int = 80
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def suite_dict(self) -> dict:
        if self.dataset_root:
            return load_suite_config(Path(self.dataset_root)).to_dict()
        suite = {
            "type": self.suite_type,
            "tasks": self.tasks or (self.task or ""),
            "obs_type": self.obs_type,
            "image_size": self.image_size,
        }
        if self.max_episode_steps is not None:
            suite["max_episode_steps"] = self.max_episode_steps
        return suite

    def __post_init__(self):
        suite = make_suite(suite_config_from_dict(self.suite_dict()))
        if self.task is None:
            self.task = suite.tasks[0]
        elif (
            self.task not in suite.tasks
        ):  # a short name (e.g. `push` for FetchPush-v4): the suite resolves it
            self.task = make_suite(suite_config_from_dict({**self.suite_dict(), "tasks": self.task})).tasks[0]
        self.fps = suite.fps
        self.features, self.features_map = {}, {}
        for key, ft in dataset_features(suite).items():  # one source of truth for the feature specs
            env_key = ENV_KEYS.get(key) or "pixels/" + key.rsplit(".", 1)[-1]
            self.features[env_key] = PolicyFeature(
                type=FEATURE_TYPES.get(env_key, FeatureType.VISUAL), shape=tuple(ft["shape"])
            )
            self.features_map[env_key] = key

    @property
    def package_name(self) -> str:
        return "adademo_lerobot.lerobot_plugins.env"

    @property
    def gym_id(self) -> str:
        return GYM_ID

    @property
    def gym_kwargs(self) -> dict:
        return {"suite": self.suite_dict(), "task": self.task}
