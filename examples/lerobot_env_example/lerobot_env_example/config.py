from dataclasses import dataclass

from lerobot.envs.configs import EnvConfig


@EnvConfig.register_subclass("example")  # --suite.env.type=example
@dataclass
class ExampleEnv(EnvConfig):
    task: str | None = "PointReach-v0"  # the default --suite.tasks: a gym id without its namespace
    fps: int = 10  # the dataset's frame rate
    episode_length: int = 50  # the default --suite.max_episode_steps
    tolerance: float = 0.05  # a field of this env: --suite.env.tolerance=0.02

    @property
    def package_name(self) -> str:  # the module that registers the gym ids, and their namespace
        return "lerobot_env_example"

    @property
    def gym_kwargs(self) -> dict:  # what gym.make passes on to the env's constructor
        return {"tolerance": self.tolerance, "max_episode_steps": self.episode_length}
