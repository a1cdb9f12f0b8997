"""adademo's LeRobot plugins: the `adademo` env type (stock `lerobot-eval` on our suites) and, for real-robot
rounds, the `adademo_sim` robot and `adademo_scripted` teleoperator. LeRobot imports them by itself through the
tiny distributions in `plugins/` (named `lerobot_env_*`, `lerobot_robot_*`, `lerobot_teleoperator_*`)."""
