"""`--teleop.type=adademo_scripted`: MetaWorld's scripted expert as a LeRobot Teleoperator for the `adademo_sim`
robot, standing in for the person at a leader arm. It also answers the person's keys through LeRobot's
teleoperator-events convention (`get_teleop_events`): success or failure as the scene reports it, the end of an
episode a few frames after success, and an intervention (the person taking over) once it has watched the robot go
where it would not (its action and the robot's differ by more than a threshold for several steps in a row)."""

from __future__ import annotations

import numpy as np
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
        self._watched = (None, -1)  # (scene, step) last compared
        self._disagreeing, self._intervening = 0, False

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

    def _expert(self, task: str):
        if task not in self._experts:
            from adademo_lerobot.collectors.metaworld_scripted import scripted_policy

            self._experts[task] = scripted_policy(task)
        return self._experts[task]

    def get_action(self) -> dict:
        robot = connected_sim()
        command = self._expert(robot.task)(robot.env_observation)
        return dict(zip(ACTIONS, (float(v) for v in command), strict=True))

    def _takes_over(self, robot) -> bool:
        """Whether it has taken over this scene: compares its action with each new action the robot took."""
        scene = (robot.scene_seed, id(robot))
        if self._watched[0] != scene or robot.scene_steps < self._watched[1]:  # a new scene
            self._watched, self._disagreeing, self._intervening = (scene, -1), 0, False
        if not self._intervening and robot.last_step is not None and robot.scene_steps != self._watched[1]:
            observation, taken = robot.last_step
            mine = np.clip(np.asarray(self._expert(robot.task)(observation), np.float64), -1.0, 1.0)
            apart = np.linalg.norm(mine - taken) > self.config.takeover_threshold
            self._disagreeing = self._disagreeing + 1 if apart else 0
            self._intervening = self._disagreeing >= self.config.takeover_consecutive
            self._watched = (scene, robot.scene_steps)
        return self._intervening

    def get_teleop_events(self) -> dict:
        robot = connected_sim()
        return {
            TeleopEvents.SUCCESS: robot.success,
            TeleopEvents.FAILURE: False,
            TeleopEvents.TERMINATE_EPISODE: robot.success
            and robot.steps_since_success >= self.config.post_success_frames,
            TeleopEvents.RERECORD_EPISODE: False,
            TeleopEvents.IS_INTERVENTION: self._takes_over(robot),
        }

    def send_feedback(self, feedback: dict) -> None:
        pass

    def disconnect(self) -> None:
        self._connected = False
