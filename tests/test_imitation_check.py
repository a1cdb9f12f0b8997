"""benchmarks/imitation_check.py: the share of the demonstrations' action variance that other demonstrations'
nearest states explain (the column that says, before any training, whether the data can be imitated)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import load_benchmark

imitation_check = load_benchmark("imitation_check")


def demonstrations(episodes: int = 20, steps: int = 60, seed: int = 0):
    """Episodes that sweep a 3-D state along random lines; an unused action dimension stays at zero."""
    rng = np.random.default_rng(seed)
    states = np.concatenate(
        [np.linspace(rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3), steps) for _ in range(episodes)]
    )
    episode = np.repeat(np.arange(episodes), steps)
    return rng, states, episode


def test_actions_that_follow_the_state_are_explained_and_independent_ones_are_not():
    rng, states, episode = demonstrations()
    policy = np.stack([np.sin(2 * states[:, 0]), states[:, 1] * states[:, 2], np.zeros(len(states))], axis=1)
    consistent = imitation_check.actions_explained_by_state(states, policy, episode)
    assert consistent > 0.8
    # Each demonstration its own way: the mean of 5 unrelated actions leaves 1 + 1/5 of the variance, -0.2.
    noise = rng.normal(size=policy.shape)
    assert abs(imitation_check.actions_explained_by_state(states, noise, episode) + 0.2) < 0.1
    # The same rule, each episode offset by its own constant: half the variance is the episode's own.
    offset = policy + np.repeat(rng.normal(size=(20, 3)), 60, axis=0) * policy.std(axis=0)
    assert -0.2 < imitation_check.actions_explained_by_state(states, offset, episode) < consistent - 0.3


def test_neighbours_come_from_other_episodes_only():
    """Each episode's actions are its own constant: its own frames would predict them exactly, other episodes'
    do not, so a score near 1 would mean the frame's own episode was used."""
    rng, states, episode = demonstrations(episodes=10, steps=200, seed=1)
    own_constant = np.repeat(rng.normal(size=(10, 2)), 200, axis=0)
    assert imitation_check.actions_explained_by_state(states, own_constant, episode) < 0.3


def test_a_folder_that_is_not_a_dataset_or_run_is_one_error_line(tmp_path):
    script = Path(imitation_check.__file__)
    for flag, says in (("--dataset", "is not a LeRobot dataset"), ("--run_dir", "is not a run folder")):
        proc = subprocess.run(
            [sys.executable, str(script), flag, str(tmp_path)], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 2 and says in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
