"""adademo-run: the whole AdaDemo loop from a recipe (collect, train, then rounds of expand/retrain/evaluate)."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.run import RunConfig


def main() -> None:
    run_command("adademo_lerobot.loop.run:run", RunConfig)


if __name__ == "__main__":
    main()
