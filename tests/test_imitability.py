"""The imitability score (`loop/imitability.py`): the share of a task's demonstration actions that the nearest
states of its other demonstrations explain, which `adademo-report` reads as "can a policy imitate these?"."""

import numpy as np
import pytest
from conftest import run_cli

from adademo_lerobot.loop.imitability import (
    AGREE,
    DISAGREE,
    MIN_DEMONSTRATIONS,
    actions_explained_by_state,
    agreement_of,
    agreement_reading,
    demonstration_agreement,
)


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
    consistent = actions_explained_by_state(states, policy, episode)
    assert consistent > 0.8
    # Each demonstration its own way: the mean of 5 unrelated actions leaves 1 + 1/5 of the variance, -0.2.
    noise = rng.normal(size=policy.shape)
    assert abs(actions_explained_by_state(states, noise, episode) + 0.2) < 0.1
    # The same rule, each episode offset by its own constant: half the variance is the episode's own.
    offset = policy + np.repeat(rng.normal(size=(20, 3)), 60, axis=0) * policy.std(axis=0)
    assert -0.2 < actions_explained_by_state(states, offset, episode) < consistent - 0.3


def test_neighbours_come_from_other_episodes_only():
    """Each episode's actions are its own constant: its own frames would predict them exactly, other episodes'
    do not, so a score near 1 would mean the frame's own episode was used."""
    rng, states, episode = demonstrations(episodes=10, steps=200, seed=1)
    own_constant = np.repeat(rng.normal(size=(10, 2)), 200, axis=0)
    assert actions_explained_by_state(states, own_constant, episode) < 0.3


def test_too_few_or_motionless_demonstrations_have_no_score():
    rng, states, episode = demonstrations(episodes=3, steps=10)
    ranges = [range(0, 10), range(10, 20), range(20, 30)]
    assert agreement_of(np.zeros((30, 2)), states, ranges) is None  # no action dimension moves
    assert agreement_of(rng.normal(size=(30, 2)), states, ranges[:1]) is None
    assert agreement_of(rng.normal(size=(30, 2)), states, ranges) is not None


@pytest.mark.parametrize(
    ("score", "says"),
    [
        (None, f"needs {MIN_DEMONSTRATIONS}"),
        (-0.37, "disagree"),
        (DISAGREE - 0.01, "disagree"),
        (DISAGREE, "partly consistent"),
        (AGREE - 0.01, "partly consistent"),
        (AGREE, ": consistent"),
        (0.95, ": consistent"),
    ],
)
def test_the_reading_of_a_score(score, says):
    assert says in agreement_reading(score)


def test_a_real_dataset_scored_per_task_from_its_first_demonstrations(tmp_path):
    """Scripted reach-v3 and push-v3 demonstrations collected as a user would: both read as not disagreeing (the
    scripted experts are consistent), and a task with fewer than MIN_DEMONSTRATIONS has no score."""
    root = tmp_path / "demo"
    run_cli(
        "adademo-collect", "--suite.type=metaworld", "--suite.tasks=reach-v3,push-v3",
        f"--episodes_per_task={MIN_DEMONSTRATIONS}", "--dataset.repo_id=local/demo", f"--dataset.root={root}",
        "--seed=0",
    )  # fmt: skip
    scored = demonstration_agreement(root, ["reach-v3", "push-v3"])
    assert [(a.task, a.demonstrations) for a in scored] == [("reach-v3", 10), ("push-v3", 10)]
    for a in scored:
        assert a.score is not None and a.score >= DISAGREE and "disagree" not in a.reading, a
    # Only the first demonstrations count: 9 of each are too few, however many the dataset has.
    for a in demonstration_agreement(root, ["reach-v3", "push-v3"], per_task=MIN_DEMONSTRATIONS - 1):
        assert a.demonstrations == MIN_DEMONSTRATIONS - 1 and a.score is None and "too few" in a.reading
