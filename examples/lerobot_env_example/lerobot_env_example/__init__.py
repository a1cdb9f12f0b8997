"""A minimal LeRobot env plugin: a point in the plane that must reach a goal (docs/lerobot-env.md)."""

import gymnasium as gym

from lerobot_env_example.config import ExampleEnv  # noqa: F401  (registers --suite.env.type=example)

# The gym id is `<package_name>/<task>`: the namespace is the config's package_name, the name a --suite.tasks value.
gym.register(id="lerobot_env_example/PointReach-v0", entry_point="lerobot_env_example.env:PointReachEnv")
