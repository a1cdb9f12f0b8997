"""adademo-collect: build the initial LeRobot dataset of expert demonstrations."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import CollectConfig


def main() -> None:
    run_command(
        "adademo_lerobot.loop.collect:run_collect",
        CollectConfig,
        resume="rerun the same command with --resume=true to keep what was collected and go on",
    )


if __name__ == "__main__":
    main()
