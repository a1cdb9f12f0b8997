"""adademo-push: push an adademo dataset (with meta/adademo and a per-round dataset card) to the hub."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import PushConfig


def main() -> None:
    run_command("adademo_lerobot.loop.push:run_push", PushConfig)


if __name__ == "__main__":
    main()
