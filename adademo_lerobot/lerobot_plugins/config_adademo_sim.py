"""`--robot.type=adademo_sim`: a MetaWorld scene behind LeRobot's Robot interface (config; kept light so LeRobot's
plugin discovery imports it at once). The robot is `adademo_sim.AdademoSim`."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots.config import RobotConfig


@RobotConfig.register_subclass("adademo_sim")
@dataclass
class AdademoSimConfig(RobotConfig):
    # The MetaWorld task the scene is set up for.
    task: str = "reach-v3"
    # Every task the robot is used for, comma-separated (the scene readings end with a one-hot over them, as our
    # datasets' environment_state does); default: just `task`.
    tasks: str | None = None
    # The scene camera, like a real arm's (rendered by MuJoCo); empty for none.
    camera: str = "corner2"
    image_size: int = 64
    # The objects' positions as sensor readings (a motion-capture system's): state observations without a camera.
    scene_state: bool = False
    # Steps of the simulated clock per second (MetaWorld's control rate).
    fps: int = 80
    # The layout of the first scene; later scenes are drawn from it unless set with `reset_scene(seed)`.
    seed: int = 0

    def task_list(self) -> list[str]:
        tasks = [t.strip() for t in (self.tasks or self.task).split(",") if t.strip()]
        return tasks if self.task in tasks else [*tasks, self.task]
