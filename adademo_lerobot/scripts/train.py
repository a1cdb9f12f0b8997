"""adademo-train: train ACT or Diffusion with AdaDemo's episode-weighted sampler."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.configs import TrainCommandFlags


def main() -> None:
    run_command("adademo_lerobot.train:train", TrainCommandFlags, "adademo_lerobot.train:AdaDemoTrainConfig")


if __name__ == "__main__":
    main()
