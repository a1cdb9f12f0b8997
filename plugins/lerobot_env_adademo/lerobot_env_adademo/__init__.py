"""Registers `--env.type=adademo` with LeRobot (imported by LeRobot's third-party plugin discovery)."""

import adademo_lerobot.lerobot_plugins.env  # noqa: F401
