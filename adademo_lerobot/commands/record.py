"""adademo-record: one AdaDemo round on a robot, with a person in the loop."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import RecordConfig


def main() -> None:
    run_command("adademo_lerobot.loop.record:run_record", RecordConfig)


if __name__ == "__main__":
    main()
