"""`--robot.type=adademo_sim`: a MetaWorld scene behind LeRobot's Robot interface, so everything written for real
arms (`lerobot-record`, `lerobot-replay`, `lerobot-teleoperate`, `adademo-record`) runs on it without hardware.

What it reads and takes is a real arm's: the end effector's position and gripper opening (`x.pos`, `y.pos`, `z.pos`,
`gripper.pos`), a scene camera, and end-effector velocity commands (`x.vel`, `y.vel`, `z.vel`, `gripper.vel`).
`scene_state=true` adds the objects' positions as sensor readings (a motion-capture system's), for CPU runs
without a camera. Beyond the Robot interface it has what only a simulator can do, and adademo-record uses when it
is there: `reset_scene(seed)` puts the scene in a given layout (a person does this on a real robot) and
`select_task(task)` sets up another task.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from adademo_lerobot.core.seeds import derive_seed
from adademo_lerobot.lerobot_plugins.config_adademo_sim import AdademoSimConfig
from adademo_lerobot.suites.metaworld import ROBOT_ACTIONS as ACTIONS, ROBOT_JOINTS as JOINTS

# The simulated robots connected in this process, latest last: the scripted teleoperator drives the scene of the
# latest (LeRobot builds robot and teleoperator separately, and only the robot owns a scene).
_CONNECTED: list[AdademoSim] = []


def connected_sim() -> AdademoSim:
    if not _CONNECTED:
        raise DeviceNotConnectedError("the adademo_scripted teleoperator needs a connected adademo_sim robot")
    return _CONNECTED[-1]


class Simulated:
    """What a simulated device answers to LeRobot's setup calls: nothing to calibrate or configure."""

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass


class AdademoSim(Simulated, Robot):
    config_class = AdademoSimConfig
    name = "adademo_sim"
    # adademo-record: no real-time pacing, and scenes are set with reset_scene instead of by a person.
    simulated = True

    def __init__(self, config: AdademoSimConfig):
        super().__init__(config)
        self.config = config
        self.cameras: dict = {}  # LeRobot's loops read this; the scene camera is rendered by the simulator
        self.task = config.task
        self._suite = None
        self._envs: dict = {}
        self._obs: dict | None = None
        self._scenes = 0
        self.scene_seed: int | None = None
        self.success = False
        self.steps_since_success = 0
        # What the last action was taken in and what it was (a watching person compares it with their own), and
        # how many steps the current scene has had.
        self.last_step: tuple[dict, np.ndarray] | None = None
        self.scene_steps = 0

    @cached_property
    def observation_features(self) -> dict:
        features: dict = dict.fromkeys(JOINTS, float)
        if self.config.scene_state:
            features |= {f"scene.{i}": float for i in range(self._scene_dim())}
        if self.config.camera:
            features[self.config.camera] = (self.config.image_size, self.config.image_size, 3)
        return features

    @cached_property
    def action_features(self) -> dict:
        return dict.fromkeys(ACTIONS, float)

    def _scene_dim(self) -> int:
        from adademo_lerobot.suites.metaworld import RAW_OBS_DIM

        return RAW_OBS_DIM + len(self.config.task_list())

    @property
    def is_connected(self) -> bool:
        return self._suite is not None

    def connect(self, calibrate: bool = True) -> None:
        if self.is_connected:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

        suite_config = MetaWorldSuiteConfig(
            tasks=",".join(self.config.task_list()),
            obs_type="pixels_state" if self.config.camera else "state",
            image_size=self.config.image_size,
            camera=self.config.camera or "corner2",
            max_episode_steps=10**9,  # episodes end when the person (or the recorder's clock) says so
        )
        self._suite = suite_config.build()
        _CONNECTED.append(self)
        self.reset_scene()

    def _env(self):
        if self.task not in self._envs:
            self._envs[self.task] = self._suite.make_env(self.task, terminate_on_success=False)
        return self._envs[self.task]

    def select_task(self, task: str) -> None:
        if task not in self.config.task_list():
            raise ValueError(
                f"{task!r} is not one of this robot's tasks ({self.config.tasks or self.config.task})"
            )
        self.task = task
        self.reset_scene()

    def reset_scene(self, seed: int | None = None) -> int:
        """Put the scene in the layout of `seed` (default: the next of the robot's own draws); returns the seed."""
        if not self.is_connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        if seed is None:
            seed = derive_seed(self.config.seed, self.task, self._scenes)
            self._scenes += 1
        state = self._suite.sample_initial_state(self.task, seed)
        self._obs, _ = self._env().reset(options={"initial_state": state})
        self.scene_seed, self.success, self.steps_since_success = seed, False, 0
        self.last_step, self.scene_steps = None, 0
        return seed

    @property
    def env_observation(self) -> dict:
        """The simulator's own observation of the scene (what the scripted expert reads)."""
        return self._obs

    def get_observation(self) -> dict:
        if not self.is_connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        obs = dict(zip(JOINTS, (float(v) for v in self._obs["agent_pos"]), strict=True))
        if self.config.scene_state:
            obs |= {f"scene.{i}": float(v) for i, v in enumerate(self._obs["environment_state"])}
        if self.config.camera:
            obs[self.config.camera] = self._obs["pixels"][self.config.camera]
        return obs

    def send_action(self, action: dict) -> dict:
        if not self.is_connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        command = np.clip(np.array([float(action[k]) for k in ACTIONS], dtype=np.float32), -1.0, 1.0)
        self.last_step = (self._obs, command)
        self.scene_steps += 1
        self._obs, _, _, _, info = self._env().step(command)
        if self.success or info["is_success"]:
            self.steps_since_success += self.success
            self.success = True
        return dict(zip(ACTIONS, (float(v) for v in command), strict=True))

    def disconnect(self) -> None:
        if not self.is_connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        for env in self._envs.values():
            env.close()
        self._envs, self._suite = {}, None
        _CONNECTED.remove(self)
