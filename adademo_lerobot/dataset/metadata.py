"""Reading what adademo needs from a LeRobot v3.0 dataset: the suite that built it and each episode's provenance.

Both survive LeRobot's own dataset tools, or are rebuilt from what those keep:

- the suite is `meta/adademo/suite.json`; a dataset made by `merge_datasets`, `aggregate_datasets`,
  `delete_episodes` or `split_dataset` (which copy no extra files) gets it back from what they do keep: the
  suite family (`robot_type` in `meta/info.json`), the task strings (`meta/tasks.parquet`), the one-hot position
  of each task (read from one frame of each task) and the camera features; the step limit is the suite's default;
- the per-episode `adademo/*` columns of `meta/episodes` are kept by merge/aggregate; delete/split drop them, and
  episodes without them (also those of datasets recorded elsewhere) count as imported: round 0, no initial state.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.compute as pc
import pyarrow.parquet as pq

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.interventions import apply_provenance, intervention_flags
from adademo_lerobot.dataset.layout import (
    COL_COLLECTOR,
    COL_INITIAL_STATE,
    COL_ROUND,
    COL_SEED,
    COL_SOURCE,
    COL_START_STATE,
    COL_START_STEP,
    COL_SUITE,
    EPISODE_COLUMNS,
    IMPORTED_SOURCE,
    SUITE_FILE,
)
from adademo_lerobot.suites import SuiteConfig, suite_config_from_dict

ENV_STATE_KEY = "observation.environment_state"
IMAGES_PREFIX = "observation.images."


def has_dataset(root: str | Path) -> bool:
    return (Path(root) / "meta" / "info.json").exists()


def episode_files(root: str | Path) -> list[Path]:
    return sorted((Path(root) / "meta" / "episodes").glob("chunk-*/file-*.parquet"))


def data_files(root: str | Path) -> list[Path]:
    return sorted((Path(root) / "data").glob("chunk-*/file-*.parquet"))


def load_suite_config(root: str | Path, override: SuiteConfig | None = None) -> SuiteConfig:
    """The suite of the dataset at `root`: its suite.json, else `override` (the user's --suite.* flags), else
    rebuilt from what LeRobot's own files say."""
    root = Path(root)
    path = root / SUITE_FILE
    if path.exists():
        return suite_config_from_dict(json.loads(path.read_text()))
    if override is not None:
        return override
    return rebuild_suite_config(root)


def try_load_suite_config(root: str | Path) -> SuiteConfig | None:
    """The suite if the dataset says which it is, else None (a dataset recorded elsewhere)."""
    try:
        return load_suite_config(root)
    except AdaDemoError:
        return None


def rebuild_suite_config(root: Path) -> SuiteConfig:
    """The suite, from LeRobot's own files (for datasets whose suite.json a LeRobot tool did not copy)."""
    info = read_info(root)
    kind = info.get("robot_type")
    how = "pass the suite flags (--suite.type=metaworld|fetch|adroit --suite.tasks=task1,task2,...)"
    try:
        config = suite_config_from_dict({"type": kind})
    except AdaDemoError:
        raise AdaDemoError(
            f"{root} is not an adademo dataset (no {SUITE_FILE}, and its robot_type {kind!r} is not a suite "
            f"family): {how}, or create one with `adademo-collect`"
        ) from None
    features = info.get("features", {})
    env_dim = features.get(ENV_STATE_KEY, {}).get("shape", [0])[0]
    tasks_path = root / "meta" / "tasks.parquet"
    tasks = pd.read_parquet(tasks_path) if tasks_path.exists() else pd.DataFrame()
    task_names = list(tasks.index) if len(tasks) else []
    num_tasks = env_dim - config.suite_class().layout_dim
    if num_tasks < 1 or len(task_names) != num_tasks:
        raise AdaDemoError(
            f"cannot rebuild the suite of {root}: no {SUITE_FILE}, and its {len(task_names)} task(s) do not fill the "
            f"{max(num_tasks, 0)}-task one-hot of {ENV_STATE_KEY}; {how}"
        )
    config.tasks = ",".join(order_by_onehot(root, task_names, tasks, num_tasks))
    cameras = [k[len(IMAGES_PREFIX) :] for k, ft in features.items() if k.startswith(IMAGES_PREFIX)]
    if cameras:
        config.obs_type, config.camera = "pixels_state", cameras[0]
        config.image_size = int(features[IMAGES_PREFIX + cameras[0]]["shape"][0])
    return config


def order_by_onehot(root: Path, task_names: list[str], tasks: pd.DataFrame, num_tasks: int) -> list[str]:
    """Task names in one-hot order, read from the last `num_tasks` values of one frame of each task."""
    position: dict[str, int] = {}
    for path in data_files(root):
        table = pq.read_table(path, columns=["task_index", ENV_STATE_KEY])
        for name in task_names:
            if name in position:
                continue
            rows = table.filter(pc.equal(table["task_index"], int(tasks.loc[name, "task_index"])))
            if rows.num_rows:
                position[name] = int(np.argmax(np.asarray(rows[ENV_STATE_KEY][0].as_py())[-num_tasks:]))
        if len(position) == len(task_names):
            break
    if sorted(position.values()) != list(range(num_tasks)):
        raise AdaDemoError(f"cannot tell the one-hot order of the tasks of {root} from its frames")
    return sorted(position, key=position.get)


def imported_episode_values(suite_name: str) -> dict[str, object]:
    """What an episode without our columns reads as (and is given when we first append): imported, round 0, no
    seed, no initial or start state (empty lists), start step 0, the dataset's suite (its robot type)."""
    return {
        COL_INITIAL_STATE: [],
        COL_SEED: -1,
        COL_ROUND: 0,
        COL_SOURCE: IMPORTED_SOURCE,
        COL_COLLECTOR: "",
        COL_SUITE: suite_name,
        COL_START_STEP: 0,
        COL_START_STATE: [],
    }


def read_episode_metadata(root: str | Path) -> pd.DataFrame:
    """Per-episode metadata (task, length, frame range, `adademo/*` columns) indexed by `episode_index`.

    Episodes without adademo columns are reported as imported (round 0, no initial state), or, in a dataset whose
    frames carry LeRobot's `intervention` flag, as corrections and the policy's own (`dataset/interventions.py`)."""
    root = Path(root)
    files = episode_files(root)
    base = ["episode_index", "tasks", "length", "dataset_from_index", "dataset_to_index"]
    if not files:
        return pd.DataFrame(columns=["task", "length", *EPISODE_COLUMNS]).rename_axis("episode_index")
    tables, imported = [], []
    suite_name = read_info(root).get("robot_type") or ""
    for f in files:
        names = pq.read_schema(f).names
        df = pq.read_table(f, columns=[c for c in base + list(EPISODE_COLUMNS) if c in names]).to_pandas()
        imported += [COL_SOURCE not in df.columns] * len(df)
        for col, value in imported_episode_values(suite_name).items():
            if col not in df.columns:
                df[col] = [np.zeros(0)] * len(df) if isinstance(value, list) else value
        tables.append(df)
    df = pd.concat(tables, ignore_index=True)
    # LeRobot's DAgger data: corrections and the policy's own episodes (its frames are read only when some
    # episodes still lack our columns: after our first append they carry the reading)
    flags = intervention_flags(root) if any(imported) else None
    if flags is not None:
        apply_provenance(df, flags, np.asarray(imported, dtype=bool))
    df["task"] = [t[0] if len(t) else "" for t in df.pop("tasks")]
    for col in (COL_INITIAL_STATE, COL_START_STATE):
        df[col] = [np.asarray(v, dtype=np.float64) for v in df[col]]
    return df.set_index("episode_index").sort_index()


def check_same_suite(stored: SuiteConfig, requested: SuiteConfig) -> None:
    a, b = stored.canonical().to_dict(), requested.canonical().to_dict()
    diffs = [
        f"{k}: dataset has {a.get(k)!r}, command has {b.get(k)!r}"
        for k in sorted(set(a) | set(b))
        if a.get(k) != b.get(k)
    ]
    if diffs:
        raise AdaDemoError(
            "the dataset was collected with another suite configuration (" + "; ".join(diffs) + ")"
        )
