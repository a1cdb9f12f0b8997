"""adademo-record: one AdaDemo round on a robot, with a person in the loop."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.record import RecordConfig


def main() -> None:
    run_command("adademo_lerobot.record:run_record", RecordConfig)


if __name__ == "__main__":
    main()
