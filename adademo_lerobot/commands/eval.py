"""adademo-eval: success of a LeRobot policy per task and per initial state."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import EvalCommandConfig


def main() -> None:
    run_command("adademo_lerobot.loop.evaluate:run_eval", EvalCommandConfig)


if __name__ == "__main__":
    main()
