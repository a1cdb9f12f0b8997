"""adademo-expand: one round of adaptive (or uniform) demonstration expansion."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.configs import ExpandConfig
from adademo_lerobot.expand import run_expand


def main() -> None:
    run_command(run_expand, ExpandConfig)


if __name__ == "__main__":
    main()
