from dataclasses import dataclass

import gymnasium as gym
from lerobot.envs.configs import EnvConfig
from lerobot_env_example.config import ExampleEnv
from lerobot_env_example.env import PointReachEnv


# No package_name: LeRobot then imports `gym_example_default_package_name`.
@EnvConfig.register_subclass("example_default_package_name")
@dataclass
class DefaultPackageName(EnvConfig):
    task: str | None = "PointReach-v0"

    @property
    def gym_kwargs(self) -> dict:
        return {}


@EnvConfig.register_subclass("example_wrong_package_name")
@dataclass
class WrongPackageName(ExampleEnv):
    @property
    def package_name(self) -> str:  # a module that exists, but not the namespace of the gym ids
        return "lerobot_env_example.env"


@EnvConfig.register_subclass("example_no_gym_kwargs")
@dataclass
class NoGymKwargs(EnvConfig):  # no gym_kwargs: the config cannot even be made
    task: str | None = "PointReach-v0"

    @property
    def package_name(self) -> str:
        return "lerobot_env_example"


class DiscreteActions(PointReachEnv):
    def __init__(self, tolerance: float = 0.05):
        super().__init__(tolerance)
        self.action_space = gym.spaces.Discrete(4)  # left, right, down, up


gym.register(id="lerobot_env_example_broken/PointReachDiscrete-v0", entry_point=DiscreteActions)


@EnvConfig.register_subclass("example_discrete")
@dataclass
class Discrete(ExampleEnv):
    task: str | None = "PointReachDiscrete-v0"

    @property
    def package_name(self) -> str:
        return "lerobot_env_example_broken"
