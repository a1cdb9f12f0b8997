"""Our suites as a LeRobot env type, so stock `lerobot-eval` evaluates our checkpoints on our tasks:

    lerobot-eval --policy.path=CKPT --env.type=adademo --env.discover_packages_path=adademo_lerobot.envs \\
        --env.dataset_root=DATASET --env.task=reach-v3 --eval.n_episodes=10 --eval.batch_size=10

`--env.dataset_root` rebuilds the suite from a dataset's `meta/adademo/suite.json` (or give
`--env.suite_type/--env.tasks/--env.obs_type`). One task per invocation: LeRobot's env config names one task.
`reset(seed=k)` starts from the suite's initial state for seed k, so lerobot-eval's seeds are reproducible.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig


GYM_ID = "adademo/SuiteTask-v0"



def make_suite_task_env(suite: dict, task: str, **_):
    from adademo_lerobot.suites.base import SuiteConfig, make_suite

    return make_suite(SuiteConfig.from_dict(suite)).make_env(task, terminate_on_success=True)


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
            return json.loads((Path(self.dataset_root) / "meta" / "adademo" / "suite.json").read_text())
        suite = {"type": self.suite_type, "tasks": self.tasks or (self.task or ""), "obs_type": self.obs_type,
                 "image_size": self.image_size}
        if self.max_episode_steps is not None:
            suite["max_episode_steps"] = self.max_episode_steps
        return suite

    def __post_init__(self):
        from adademo_lerobot.suites.base import SuiteConfig, make_suite

        suite = make_suite(SuiteConfig.from_dict(self.suite_dict()))
        if self.task is None:
            self.task = suite.tasks[0]
        elif self.task not in suite.tasks:  # a short name (e.g. `push` for FetchPush-v4): the suite resolves it
            self.task = make_suite(SuiteConfig.from_dict({**self.suite_dict(), "tasks": self.task})).tasks[0]
        self.fps = suite.fps
        self.features = {
            "action": PolicyFeature(type=FeatureType.ACTION, shape=(suite.action_dim,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(suite.state_dim,)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(suite.env_state_dim,)),
        }
        self.features_map = {"action": "action", "agent_pos": "observation.state",
                             "environment_state": "observation.environment_state"}
        if suite.config.obs_type == "pixels_state":
            camera = getattr(suite.config, "camera", "camera")
            size = suite.config.image_size
            self.features[f"pixels/{camera}"] = PolicyFeature(type=FeatureType.VISUAL, shape=(size, size, 3))
            self.features_map[f"pixels/{camera}"] = f"observation.images.{camera}"

    @property
    def package_name(self) -> str:
        return "adademo_lerobot.envs"

    @property
    def gym_id(self) -> str:
        return GYM_ID

    @property
    def gym_kwargs(self) -> dict:
        return {"suite": self.suite_dict(), "task": self.task}
