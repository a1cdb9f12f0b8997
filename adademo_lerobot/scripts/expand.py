"""adademo-expand: one round of adaptive (or uniform) demonstration expansion."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.configs import ExpandConfig


def main() -> None:
    run_command("adademo_lerobot.expand:run_expand", ExpandConfig)


if __name__ == "__main__":
    main()
