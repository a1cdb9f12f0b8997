"""adademo-train: train ACT or Diffusion with AdaDemo's episode-weighted sampler."""

from adademo_lerobot.cli import run_command
from adademo_lerobot.train import AdaDemoTrainConfig, train


def main() -> None:
    run_command(train, AdaDemoTrainConfig, policy_types=True)


if __name__ == "__main__":
    main()
