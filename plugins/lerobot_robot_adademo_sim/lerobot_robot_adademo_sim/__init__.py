"""Registers `--robot.type=adademo_sim` with LeRobot (imported by LeRobot's third-party plugin discovery)."""

import adademo_lerobot.lerobot_plugins.config_adademo_sim  # noqa: F401
