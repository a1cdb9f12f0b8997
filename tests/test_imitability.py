"""The imitability score (`dataset/imitability.py`): the share of a task's demonstration actions that the nearest
states of its other demonstrations explain, which `adademo-report` reads as "can a policy imitate these?"."""

import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import run_cli

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.imitability import (
    AGREE,
    DISAGREE,
    MIN_DEMONSTRATIONS,
    actions_explained_by_state,
    agreement_of,
    agreement_reading,
    demonstration_agreement,
    disagreement_notes,
)
from adademo_lerobot.dataset.metadata import data_files


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
    collect = (
        "adademo-collect", "--suite.type=metaworld", "--suite.tasks=reach-v3,push-v3",
        "--dataset.repo_id=local/demo", f"--dataset.root={root}", "--seed=0",
    )  # fmt: skip
    first = run_cli(*collect, f"--episodes_per_task={MIN_DEMONSTRATIONS}")
    assert "note:" not in first.stdout
    scored = demonstration_agreement(root, ["reach-v3", "push-v3"])
    assert disagreement_notes(root, ["reach-v3", "push-v3"]) == []
    # The same table for a dataset without a run folder (e.g. recorded on a robot), beside the person's work.
    shown = run_cli("adademo-report", f"--dataset_root={root}").stdout
    assert "Can a policy imitate these demonstrations?" in shown
    assert all(f"| {a.task} | 10 | {a.score:.2f} | similar states" in shown for a in scored)
    assert [(a.task, a.demonstrations) for a in scored] == [("reach-v3", 10), ("push-v3", 10)]
    for a in scored:
        assert a.score is not None and a.score >= DISAGREE and "disagree" not in a.reading, a
    # Only the first demonstrations count: 9 of each are too few, however many the dataset has.
    for a in demonstration_agreement(root, ["reach-v3", "push-v3"], per_task=MIN_DEMONSTRATIONS - 1):
        assert a.demonstrations == MIN_DEMONSTRATIONS - 1 and a.score is None and "too few" in a.reading
    # The same files with every action drawn at random: each demonstration acts its own way, and the note says so.
    rng = np.random.default_rng(0)
    for path in data_files(root):
        frames = pq.read_table(path)
        noise = rng.uniform(-1, 1, size=(len(frames), len(frames.column("action")[0])))
        column = frames.schema.get_field_index("action")
        actions = pa.FixedSizeListArray.from_arrays(
            pa.array(noise.astype(np.float32).ravel()), noise.shape[1]
        )
        pq.write_table(frames.set_column(column, "action", actions), path)
    (reach, push) = demonstration_agreement(root, ["reach-v3", "push-v3"])
    assert reach.score < DISAGREE and push.score < DISAGREE
    notes = disagreement_notes(root, ["reach-v3", "push-v3"])
    assert [n.split("'")[0] for n in notes] == ["note: reach-v3", "note: push-v3"]
    assert all("disagree with each other" in n and "more consistent expert" in n for n in notes)
    # adademo-collect says it after a collection (here one more demonstration a task, added to these files).
    more = run_cli(*collect, f"--episodes_per_task={MIN_DEMONSTRATIONS + 1}", "--resume=true")
    assert (
        "note: reach-v3's first 11 demonstrations disagree" in more.stdout
        and "note: push-v3's" in more.stdout
    )
    # A dataset with no episode yet (its info written, nothing recorded): no score, and no error either.
    empty = tmp_path / "empty"
    (empty / "meta").mkdir(parents=True)
    shutil.copy(root / "meta" / "info.json", empty / "meta" / "info.json")
    assert [(a.demonstrations, a.score) for a in demonstration_agreement(empty, ["reach-v3"])] == [(0, None)]
    # States that are not numbers, or a frame index that does not count the frames: one line, not a traceback.
    originals = {path: pq.read_table(path) for path in data_files(root)}
    for change, says in (
        (lambda t: t.set_column(t.schema.get_field_index("observation.state"), "observation.state",
                                pa.array([[float("nan")] * 39] * len(t), pa.list_(pa.float32()))), "cannot be scored"),
        (lambda t: t.set_column(t.schema.get_field_index("index"), "index",
                                pa.array(t.column("index").to_numpy() + 1000)), "frame index is not 0, 1, 2"),
    ):  # fmt: skip
        for path, frames in originals.items():
            pq.write_table(change(frames), path)
        with pytest.raises(AdaDemoError, match=says):
            demonstration_agreement(root, ["reach-v3", "push-v3"])
    for path, frames in originals.items():
        pq.write_table(frames, path)
    # Files whose actions cannot be read as rows of numbers (lists of different lengths): the score says so in one
    # line, and a collection's note does not fail the command.
    for path in data_files(root):
        frames = pq.read_table(path)
        ragged = pa.array([[0.0] * (1 + i % 2) for i in range(len(frames))], pa.list_(pa.float32()))
        pq.write_table(frames.set_column(frames.schema.get_field_index("action"), "action", ragged), path)
    with pytest.raises(AdaDemoError, match="cannot be scored"):
        demonstration_agreement(root, ["reach-v3"])
    (note,) = disagreement_notes(root, ["reach-v3", "push-v3"])
    assert note.startswith("note: the actions and states of") and "cannot be scored" in note
