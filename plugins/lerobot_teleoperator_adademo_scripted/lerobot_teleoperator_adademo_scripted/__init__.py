"""Registers `--teleop.type=adademo_scripted` with LeRobot (imported by LeRobot's third-party plugin discovery)."""

import adademo_lerobot.lerobot_plugins.config_adademo_scripted  # noqa: F401
