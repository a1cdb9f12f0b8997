"""LeRobot's human-in-the-loop datasets read as what they are, and the features our writers carry along.

`lerobot-rollout --strategy.type=dagger` (LeRobot 0.6) lets a policy drive and a person take over; every frame it
records has a bool feature `intervention` (True: the person drove it). Without `--strategy.record_autonomous` each
episode is one correction (every frame True); with it, episodes hold the policy's frames (False) with the person's
intervention segments (True) inside them. Nothing here changes such a dataset: it is a reading of LeRobot's own
files, the same for stock LeRobot and for us.

- An episode with a person's frame is a correction (`adademo/source=correction`, `adademo/start_step` = its first
  intervention frame, collector `teleop`: LeRobot does not record which teleoperator); one without is the
  policy's (`adademo/source=policy`). Episodes our commands wrote carry their own columns, which win.
- Training imitates the person's frames; the policy's own frames stay out of the imitation targets unless asked
  for (`imitation_units`, `--autonomous_weight`; `train.policy_action_mask` for the steps of an action chunk):
  in a DAgger dataset they are what the policy already does, including what it did wrong before the person took
  over.
- The person's frames and seconds are counted per round and task (`report_costs.person_work`).
- Our writers add an `intervention` value to every frame they write to such a dataset (True: what we write is
  the person's or the expert's); a dataset with any other feature our writers do not produce is refused before
  anything is recorded (`check_writable_features`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import (
    COL_COLLECTOR,
    COL_SOURCE,
    COL_START_STEP,
    CORRECTION_SOURCE,
    INTERVENTION_FEATURE,
    PERSON_COLLECTOR,
    POLICY_SOURCE,
)

# The per-frame features LeRobot's writer fills in itself (lerobot.datasets.utils.DEFAULT_FEATURES, format v3.0).
LEROBOT_FRAME_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def has_interventions(features: dict) -> bool:
    """Whether a dataset's features (info.json) tag each frame with LeRobot's `intervention` flag."""
    ft = features.get(INTERVENTION_FEATURE)
    return ft is not None and ft.get("dtype") == "bool"


def intervention_flags(root: str | Path) -> np.ndarray | None:
    """Per frame, in the dataset's `index` order: whether a person drove it; None without the feature."""
    root = Path(root)
    info = read_info(root)
    if not has_interventions(info.get("features", {})):
        return None
    flags = np.zeros(int(info.get("total_frames", 0)), dtype=bool)
    for path in sorted((root / "data").glob("chunk-*/file-*.parquet")):
        table = pq.read_table(path, columns=["index", INTERVENTION_FEATURE])
        values = table[INTERVENTION_FEATURE].to_pylist()
        flat = np.array([v[0] if isinstance(v, list) else v for v in values], dtype=bool)
        index = table["index"].to_numpy()
        if len(index) and index.max() >= len(flags):
            flags = np.pad(flags, (0, int(index.max()) + 1 - len(flags)))
        flags[index] = flat
    return flags


def episode_provenance(flags: np.ndarray, starts, ends) -> tuple[list[str], list[int]]:
    """For episodes spanning frames [start, end): their source (a correction when a person drove any frame,
    else the policy's) and start step (the first frame the person drove; 0 for the policy's)."""
    sources, steps = [], []
    for start, end in zip(starts, ends, strict=True):
        person = np.flatnonzero(flags[int(start) : int(end)])
        sources.append(CORRECTION_SOURCE if len(person) else POLICY_SOURCE)
        steps.append(int(person[0]) if len(person) else 0)
    return sources, steps


def apply_provenance(df: pd.DataFrame, flags: np.ndarray, rows: np.ndarray) -> None:
    """Set source, start step and collector of `df`'s `rows` (episodes without adademo columns) from `flags`."""
    if not rows.any():
        return
    sub = df.loc[rows]
    sources, steps = episode_provenance(flags, sub["dataset_from_index"], sub["dataset_to_index"])
    df.loc[rows, COL_SOURCE] = sources
    df.loc[rows, COL_START_STEP] = steps
    df.loc[rows, COL_COLLECTOR] = [PERSON_COLLECTOR if s == CORRECTION_SOURCE else "" for s in sources]


def segments(flags: np.ndarray, episodes: pd.DataFrame) -> pd.DataFrame:
    """Runs of frames one driver drove, within each episode: `episode_index`, `task`, `person` (bool), `start`
    (its first frame in the episode), `dataset_from_index`, `dataset_to_index` and `episode_to_index`."""
    rows = []
    for index, ep in episodes.iterrows():
        start, end = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        part = flags[start:end]
        cuts = [0, *(np.flatnonzero(part[1:] != part[:-1]) + 1).tolist(), len(part)]
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            if b > a:
                rows.append([index, ep["task"], bool(part[a]), a, start + a, start + b, end])
    columns = ["episode_index", "task", "person", "start", "dataset_from_index", "dataset_to_index"]
    return pd.DataFrame(rows, columns=[*columns, "episode_to_index"])


def imitation_units(root: str | Path, episodes: pd.DataFrame, autonomous_weight: float) -> pd.DataFrame:
    """What training samples from: the episodes themselves, or in a dataset with `intervention` frames its
    segments (`segments`): the person's (weight 1) and, when `autonomous_weight` > 0, the policy's (that weight:
    a policy segment is drawn `autonomous_weight` times as often as a person's would be), with `weight`.
    Without `intervention` frames, the successful rollouts a round kept (`--keep_successes`,
    `adademo/source=policy`) are the policy's: weight `autonomous_weight`, left out at 0."""
    flags = intervention_flags(root)
    if flags is None:
        if COL_SOURCE not in episodes.columns or not (episodes[COL_SOURCE] == POLICY_SOURCE).any():
            return episodes
        weight = np.where(episodes[COL_SOURCE] == POLICY_SOURCE, float(autonomous_weight), 1.0)
        return episodes.assign(weight=weight)[weight > 0]
    units = segments(flags, episodes)
    units["weight"] = np.where(units["person"], 1.0, float(autonomous_weight))
    units = units[units["weight"] > 0].set_index("episode_index")
    if not len(units):
        raise AdaDemoError(
            f"{root} has no frame a person drove (its `intervention` flags are all False): nothing to imitate; "
            "pass --autonomous_weight=1 to train on the policy's own frames"
        )
    return units


def carried_frame_values(features: dict, by_policy: bool = False) -> dict[str, np.ndarray]:
    """Values our writers add to every frame they write, for the dataset's features they do not produce: the
    `intervention` flag, True for the person's or the expert's frames, False for a kept policy rollout's
    (`--keep_successes`: the policy's own frames, which training weighs by `--autonomous_weight`)."""
    if has_interventions(features):
        return {INTERVENTION_FEATURE: np.array([not by_policy], dtype=bool)}
    return {}


def check_episode_stats(root: str | Path, features: dict | None = None) -> None:
    """Refuse to append to a dataset whose newest episode file has no per-episode stats for one of its features:
    LeRobot's add_features writes none for the feature it adds, any append (LeRobot's own too) then writes a file
    with them, and stock LeRobot no longer opens the dataset."""
    features = read_info(root).get("features", {}) if features is None else features
    newest = sorted((Path(root) / "meta" / "episodes").glob("chunk-*/file-*.parquet"))[-1:]
    if not newest:
        return
    names = set(pq.read_schema(newest[0]).names)
    unstated = [k for k in features if f"stats/{k}/mean" not in names]
    if unstated:
        raise AdaDemoError(
            f"{root}'s episode files have no per-episode stats for {','.join(unstated)} (LeRobot's add_features "
            "writes none for the feature it adds): any episode appended to it, by LeRobot too, would leave it "
            "unreadable by stock LeRobot; record that feature with the episodes instead, or continue on a copy "
            "without it (lerobot-edit-dataset --operation.type=remove_feature)"
        )


def check_writable_features(root: str | Path, produced: dict | list, who: str) -> None:
    """Refuse, before anything is recorded, a dataset with a feature that `who` neither produces nor carries:
    LeRobot's writer would refuse every frame of it (after the person's work)."""
    found = read_info(root).get("features", {})
    carried = carried_frame_values(found)
    unknown = [k for k in found if k not in produced and k not in carried and k not in LEROBOT_FRAME_FEATURES]
    if unknown:
        names = ",".join(unknown)
        raise AdaDemoError(
            f"{root} has feature(s) {names} that {who} does not record, so it cannot add episodes to it: "
            f"copy it without them (lerobot-edit-dataset --repo_id=REPO --root={root} --new_repo_id=REPO_NEW "
            f'--new_root=NEW_FOLDER --operation.type=remove_feature --operation.feature_names="{unknown}") '
            "and continue on the copy"
        )
    check_episode_stats(root, found)  # after: a feature we do not record says more, and how to drop it
