"""Can a policy imitate a task's demonstrations? A score per task that needs no policy and no simulation.

A policy trained by behaviour cloning maps a state to the action its training data took in similar states. If
similar states got unrelated actions (an expert that acts on noise it drew, such as a sampling planner with its
defaults), the policy averages them into an action none of them took, and more demonstrations of the same kind add
more of what it cannot fit. The score asks the data that question directly: the share of the demonstrations'
action variance (each dimension standardized) that the mean action at the nearest states (standardized) of the
task's *other* demonstrations explains, 1 - SSE / SST. Near 1: similar states got similar actions. About -0.2:
what unrelated actions give (the mean of five of them adds a fifth of the variance). Measured on Adroit
(`benchmarks/results/adroit.md`): the scripted door and relocate 0.71 and 0.95, the planner's default hammer and
pen -0.37 and -0.29 (a policy trained on them succeeds from 0 of 20 of their own starts), hammer planned with
common noise 0.37-0.45 (5-9 of 20); MetaWorld's scripted experts 0.37-0.84.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import COL_SOURCE, POLICY_SOURCE
from adademo_lerobot.dataset.metadata import data_files, read_episode_metadata

NEIGHBOURS = 5
EVERY = 5  # frames scored: every 5th (neighbouring frames of one episode say the same)
DISAGREE = 0.1  # below: no better than unrelated actions, within what 20 demonstrations can tell
AGREE = 0.5
DEMONSTRATIONS = 20  # per task: the first ones; 50 gave the same to 0.07 on Adroit
# Fewer demonstrations are too far apart for their nearest states to say anything: MetaWorld's scripted reach-v3
# scores 0.16 from 5, 0.53 from 8, 0.58 from 10 (push-v3 0.35, 0.42, 0.47).
MIN_DEMONSTRATIONS = 10


@dataclass
class Agreement:
    task: str
    demonstrations: int
    score: float | None
    reading: str

    @property
    def disagrees(self) -> bool:
        return self.score is not None and self.score < DISAGREE


def actions_explained_by_state(
    states: np.ndarray,
    actions: np.ndarray,
    episode: np.ndarray,
    neighbours: int = NEIGHBOURS,
    every: int = EVERY,
) -> float:
    """Share of the actions' variance (each dimension standardized) that the mean action of the `neighbours`
    nearest states (standardized) of *other* episodes explains, over every `every`-th frame: 1 - SSE / SST."""
    from scipy.spatial import cKDTree

    spread = actions.std(axis=0)
    used = spread > 1e-6  # dimensions the task never moves carry no variance to explain
    a = (actions[:, used] - actions[:, used].mean(axis=0)) / spread[used]
    s = (states - states.mean(axis=0)) / (states.std(axis=0) + 1e-6)
    # enough neighbours that `neighbours` of them lie outside the frame's own episode
    k = min(len(s), neighbours + int(np.bincount(episode).max()))
    _, nearest = cKDTree(s).query(s[::every], k=k)
    sse = sst = 0.0
    for i, row in zip(range(0, len(s), every), nearest, strict=True):
        others = row[episode[row] != episode[i]][:neighbours]
        sse += float(np.sum((a[others].mean(axis=0) - a[i]) ** 2))
        sst += float(np.sum(a[i] ** 2))
    return 1.0 - sse / sst


def read_actions_and_states(root: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's action and `observation.state`, in the order of the dataset's global frame index."""
    import pyarrow.parquet as pq

    def matrix(frames, name: str, dtype) -> np.ndarray:  # a list column as rows, no Python object per value
        column = frames.column(name).combine_chunks()
        values = column.flatten() if hasattr(column, "flatten") else column  # a number per frame: one column
        return values.to_numpy(zero_copy_only=False).reshape(len(column), -1).astype(dtype)

    index, actions, states = [], [], []
    # File by file: files may type a list column differently (fixed size or not).
    for path in data_files(root):
        frames = pq.read_table(path, columns=["index", "action", "observation.state"])
        index.append(frames.column("index").to_numpy())
        actions.append(matrix(frames, "action", np.float32))
        states.append(matrix(frames, "observation.state", np.float64))
    index = np.concatenate(index)
    order = np.argsort(index)
    if not np.array_equal(index[order], np.arange(len(index))):  # episodes' frame ranges are positions
        raise ValueError("the frame index is not 0, 1, 2, ... over the data files")
    return np.concatenate(actions)[order], np.concatenate(states)[order]


def agreement_of(actions: np.ndarray, states: np.ndarray, frame_ranges: list[range]) -> float | None:
    """The score of the episodes at `frame_ranges` (None: fewer than two, or no action dimension moves)."""
    if len(frame_ranges) < 2:
        return None
    own = np.concatenate([np.arange(f.start, f.stop) for f in frame_ranges])
    if not (actions[own].std(axis=0) > 1e-6).any():
        return None
    episode = np.repeat(np.arange(len(frame_ranges)), [len(f) for f in frame_ranges])
    return actions_explained_by_state(states[own], actions[own].astype(np.float64), episode)


def agreement_reading(score: float | None) -> str:
    if score is None:
        return f"too few demonstrations to tell (the score needs {MIN_DEMONSTRATIONS} of a task)"
    if score < DISAGREE:
        return (
            "the demonstrations disagree with each other: a policy averages them, and more of the same are "
            "unlikely to help; give this task a more consistent expert"
        )
    if score < AGREE:
        return "similar states got somewhat similar actions: partly consistent"
    return "similar states got similar actions: consistent"


def demonstration_agreement(
    root: Path, tasks: list[str] | None = None, per_task: int = DEMONSTRATIONS
) -> list[Agreement]:
    """Per task (default: every task of the dataset, in the order they first appear), the score of its first
    `per_task` demonstrations (a person's or an expert's; the policy's own kept rollouts are left out). Empty if
    the dataset records no `observation.state`."""
    if "observation.state" not in read_info(root).get("features", {}):
        return []
    episodes = read_episode_metadata(root)  # in episode order
    episodes = episodes[episodes[COL_SOURCE] != POLICY_SOURCE]
    if tasks is None:
        tasks = list(dict.fromkeys(episodes["task"]))
    if episodes.empty:
        return [Agreement(task, 0, None, agreement_reading(None)) for task in tasks]
    try:
        actions, states = read_actions_and_states(root)
        results = []
        for task in tasks:
            mine = episodes[episodes["task"] == task].head(per_task)
            ranges = [
                range(a, b) for a, b in zip(mine["dataset_from_index"], mine["dataset_to_index"], strict=True)
            ]
            score = agreement_of(actions, states, ranges) if len(ranges) >= MIN_DEMONSTRATIONS else None
            results.append(Agreement(task, len(ranges), score, agreement_reading(score)))
    # e.g. an action that is not a list of numbers, a NaN state, episodes past the data files' frames
    except (pa.ArrowException, ValueError, IndexError) as err:
        raise AdaDemoError(f"the actions and states of {root} cannot be scored ({err})") from None
    return results


def disagreement_notes(root: Path, tasks: list[str]) -> list[str]:
    """A `note:` line for each task whose first demonstrations disagree with each other (printed after a
    collection: before a strategy spends its budget on a task a policy may not learn)."""
    try:
        scored = demonstration_agreement(root, tasks)
    except AdaDemoError as err:  # a note is advice: it never fails the collection it follows
        return [f"note: {err}"]
    return [
        f"note: {a.task}'s first {a.demonstrations} demonstrations disagree with each other (imitability score "
        f"{a.score:.2f}, below {DISAGREE}): a policy averages them, and more of the same are unlikely to help; "
        "give this task a more consistent expert (docs/commands/report.md)"
        for a in scored
        if a.disagrees
    ]
