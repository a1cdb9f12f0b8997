"""adademo-train: train ACT or Diffusion with AdaDemo's episode-weighted sampler."""

from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.configs import TrainCommandFlags


def main() -> None:
    run_command(
        "adademo_lerobot.loop.train:train",
        TrainCommandFlags,
        "adademo_lerobot.loop.train:AdaDemoTrainConfig",
        resume="rerun the same command with --resume=true to continue from the last checkpoint",
    )


if __name__ == "__main__":
    main()
