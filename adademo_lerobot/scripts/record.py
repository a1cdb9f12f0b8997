"""adademo-record: one AdaDemo round on a robot, with a person in the loop."""

from adademo_lerobot.cli import run_command


def main() -> None:
    from adademo_lerobot.record import RecordConfig, register_devices

    register_devices()  # --robot.type / --teleop.type choices: LeRobot's devices and installed plugins
    run_command("adademo_lerobot.record:run_record", RecordConfig, policy_types=False)


if __name__ == "__main__":
    main()
