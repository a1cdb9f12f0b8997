"""adademo-expand: one round of adaptive (or uniform) demonstration expansion."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import ExpandConfig


def main() -> None:
    run_command("adademo_lerobot.loop.expand:run_expand", ExpandConfig)


if __name__ == "__main__":
    main()
