"""`--teleop.type=adademo_scripted`: MetaWorld's scripted expert as a LeRobot Teleoperator for the `adademo_sim`
robot, standing in for the person at a leader arm. It also answers the person's keys through LeRobot's
teleoperator-events convention (`get_teleop_events`): success or failure as the scene reports it, and the end of
an episode a few frames after success."""

from __future__ import annotations

from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.teleoperators.utils import TeleopEvents

from adademo_lerobot.lerobot_plugins.adademo_sim import ACTIONS, Simulated, connected_sim
from adademo_lerobot.lerobot_plugins.config_adademo_scripted import AdademoScriptedConfig


class AdademoScripted(Simulated, Teleoperator):
    config_class = AdademoScriptedConfig
    name = "adademo_scripted"

    def __init__(self, config: AdademoScriptedConfig):
        super().__init__(config)
        self.config = config
        self._connected = False
        self._experts: dict = {}

    @property
    def action_features(self) -> dict:
        return dict.fromkeys(ACTIONS, float)

    @property
    def feedback_features(self) -> dict:
        return {}

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self, calibrate: bool = True) -> None:
        self._connected = True

    def get_action(self) -> dict:
        robot = connected_sim()
        if robot.task not in self._experts:
            from adademo_lerobot.collectors.metaworld_scripted import scripted_policy

            self._experts[robot.task] = scripted_policy(robot.task)
        command = self._experts[robot.task](robot.env_observation)
        return dict(zip(ACTIONS, (float(v) for v in command), strict=True))

    def get_teleop_events(self) -> dict:
        robot = connected_sim()
        return {
            TeleopEvents.SUCCESS: robot.success,
            TeleopEvents.FAILURE: False,
            TeleopEvents.TERMINATE_EPISODE: robot.success
            and robot.steps_since_success >= self.config.post_success_frames,
            TeleopEvents.RERECORD_EPISODE: False,
            TeleopEvents.IS_INTERVENTION: True,
        }

    def send_feedback(self, feedback: dict) -> None:
        pass

    def disconnect(self) -> None:
        self._connected = False
