"""adademo's LeRobot plugins: the `adademo` env type (stock `lerobot-eval` on our suites) and, for real-robot
rounds, the `adademo_sim` robot and `adademo_scripted` teleoperator. LeRobot imports them by itself through the
tiny distributions in `plugins/` (named `lerobot_env_*`, `lerobot_robot_*`, `lerobot_teleoperator_*`).

LeRobot's commands import the plugins before anything renders: they pick the GL backend here, as our commands do.
"""

from adademo_lerobot.core.gl import prefer_loadable_backend

prefer_loadable_backend()
