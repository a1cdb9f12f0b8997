"""Reading what adademo needs from a LeRobot v3.0 dataset: the suite that built it and each episode's provenance.

Both survive LeRobot's own dataset tools, or are rebuilt from what those keep:

- the suite is `meta/adademo/suite.json`; a dataset made by `merge_datasets`, `aggregate_datasets`,
  `delete_episodes` or `split_dataset` (which copy no extra files) gets it back from what they do keep: the
  suite family (`robot_type` in `meta/info.json`), the task strings (`meta/tasks.parquet`), the one-hot position
  of each task (read from one frame of each task) and the camera features; the step limit is the suite's default;
  a dataset recorded on the simulated robot (`adademo_sim`, e.g. by lerobot-record or lerobot-rollout) is a robot
  view of a MetaWorld suite (`--suite.view=robot|robot_scene`), rebuilt from its tasks, camera and state size;
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
STATE_KEY = "observation.state"
IMAGES_PREFIX = "observation.images."
SIM_ROBOT = "adademo_sim"  # lerobot_plugins' simulated robot: its datasets are a view of a MetaWorld suite


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
    if kind == SIM_ROBOT:
        return sim_robot_suite_config(root, info)
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
    return _with_camera(config, features)


def _with_camera(config: SuiteConfig, features: dict) -> SuiteConfig:
    cameras = [k[len(IMAGES_PREFIX) :] for k, ft in features.items() if k.startswith(IMAGES_PREFIX)]
    if cameras:
        config.obs_type, config.camera = "pixels_state", cameras[0]
        config.image_size = int(features[IMAGES_PREFIX + cameras[0]]["shape"][0])
    return config


def sim_robot_suite_config(root: Path, info: dict) -> SuiteConfig:
    """The MetaWorld suite whose robot view an `adademo_sim` dataset is: its task strings are the robot's
    MetaWorld tasks (`--dataset.single_task=reach-v3`), its camera the robot's, and scene readings in
    observation.state (`--robot.scene_state=true`) make the view `robot_scene`."""
    from adademo_lerobot.suites.metaworld import PROPRIO_DIM, RAW_OBS_DIM, all_task_names

    features = info.get("features", {})
    tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
    task_names = list(tasks.index)
    unknown = [t for t in task_names if t not in all_task_names()]
    if unknown or not task_names:
        raise AdaDemoError(
            f"{root} was recorded on the simulated robot ({SIM_ROBOT}) but its task {unknown[0] if unknown else ''!r} "
            "is not a MetaWorld task: continue it with the suite flags (--suite.type=metaworld "
            "--suite.view=robot --suite.tasks=reach-v3,...), or record with --dataset.single_task=<the MetaWorld task>"
        )
    config = suite_config_from_dict({"type": "metaworld"})
    scene = int(features.get(STATE_KEY, {}).get("shape", [PROPRIO_DIM])[0]) - PROPRIO_DIM
    if scene == 0:
        config.view, config.tasks = "robot", ",".join(task_names)
    else:
        num_tasks = scene - RAW_OBS_DIM
        if num_tasks != len(task_names):
            raise AdaDemoError(
                f"{root}'s scene readings end with a {num_tasks}-task one-hot but it has {len(task_names)} "
                f"task(s): pass the robot's tasks (--robot.tasks) in order: --suite.type=metaworld "
                "--suite.view=robot_scene --suite.tasks=task1,task2,..."
            )
        config.view = "robot_scene"
        config.tasks = ",".join(order_by_onehot(root, task_names, tasks, num_tasks, key=STATE_KEY))
    return _with_camera(config, features)


def order_by_onehot(
    root: Path, task_names: list[str], tasks: pd.DataFrame, num_tasks: int, key: str = ENV_STATE_KEY
) -> list[str]:
    """Task names in one-hot order, read from the last `num_tasks` values of `key` in one frame of each task."""
    position: dict[str, int] = {}
    for path in data_files(root):
        table = pq.read_table(path, columns=["task_index", key])
        for name in task_names:
            if name in position:
                continue
            rows = table.filter(pc.equal(table["task_index"], int(tasks.loc[name, "task_index"])))
            if rows.num_rows:
                position[name] = int(np.argmax(np.asarray(rows[key][0].as_py())[-num_tasks:]))
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
