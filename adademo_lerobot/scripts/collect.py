"""adademo-collect: build the initial LeRobot dataset of expert demonstrations."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.collect import run_collect
from adademo_lerobot.configs import CollectConfig


def main() -> None:
    run_command(run_collect, CollectConfig)


if __name__ == "__main__":
    main()
