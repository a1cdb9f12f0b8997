"""adademo-run: the whole AdaDemo loop from a recipe (collect, train, then rounds of expand/retrain/evaluate)."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.run import RunConfig, run


def main() -> None:
    run_command(run, RunConfig, policy_types=True)


if __name__ == "__main__":
    main()
