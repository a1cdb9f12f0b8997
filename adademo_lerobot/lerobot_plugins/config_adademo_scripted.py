"""`--teleop.type=adademo_scripted`: MetaWorld's scripted expert as a LeRobot Teleoperator for `adademo_sim`
(config; the teleoperator is `adademo_scripted.AdademoScripted`)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("adademo_scripted")
@dataclass
class AdademoScriptedConfig(TeleoperatorConfig):
    # Frames recorded after the scene reports success before the episode is marked over (as a person lets a
    # demonstration settle before pressing the key).
    post_success_frames: int = 5
    # It watches the robot and takes over (LeRobot's intervention event) once its own action and the robot's last
    # ones differ by more than `takeover_threshold` for `takeover_consecutive` steps in a row, as
    # `--takeover.rule=disagreement` does in simulation.
    takeover_threshold: float = 1.5
    takeover_consecutive: int = 5
