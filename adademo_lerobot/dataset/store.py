"""A standard LeRobot v3.0 dataset that remembers each episode's initial state and provenance.

Our extras are extra columns in `meta/episodes` (`adademo/*`) and files under `meta/adademo/`; the format is
never forked, so stock `LeRobotDataset(repo_id, root=...)` opens every dataset written here.

Appends are transactions. LeRobot 0.4.4 writes a resumed session into new parquet/video files and rewrites only
`meta/info.json`, `meta/stats.json` and `meta/tasks.parquet`; we back those three up and list the existing files
before writing, and delete the list once `finalize()` has written the parquet footers. A write killed halfway
is rolled back on the next open: files it created are removed and the three metadata files restored. So the
dataset on disk always holds exactly the committed episodes, and appending costs O(new episodes).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any, Iterable

import datasets
import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from adademo_lerobot.collectors.base import Demonstration
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.patching import temporarily_set
from adademo_lerobot.suites.base import SuiteConfig, TaskSuite

ADADEMO_DIR = "meta/adademo"
SUITE_FILE = f"{ADADEMO_DIR}/suite.json"
TXN_FILE = f"{ADADEMO_DIR}/pending_write.json"
TXN_BACKUP_DIR = f"{ADADEMO_DIR}/pending_write_backup"
REWRITTEN_META = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")

COL_INITIAL_STATE = "adademo/initial_state"
COL_SEED = "adademo/seed"
COL_ROUND = "adademo/round"
COL_SOURCE = "adademo/source"
COL_COLLECTOR = "adademo/collector"
COL_SUITE = "adademo/suite"
EPISODE_COLUMNS = (COL_INITIAL_STATE, COL_SEED, COL_ROUND, COL_SOURCE, COL_COLLECTOR, COL_SUITE)

log = logging.getLogger(__name__)


def _provenance_dataset_class():
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    class ProvenanceLeRobotDataset(LeRobotDataset):
        """LeRobotDataset whose `save_episode` also writes extra per-episode columns into `meta/episodes`.

        LeRobot 0.4.4's metadata layer accepts `episode_metadata` but `LeRobotDataset.save_episode` does not
        expose it; the data-writing step is the one place that hands metadata on, so we add ours there.
        """

        _extra_episode_metadata: dict[str, Any] = {}

        def save_episode_with_metadata(self, episode_metadata: dict[str, Any]) -> None:
            self._extra_episode_metadata = episode_metadata
            try:
                self.save_episode()
            finally:
                self._extra_episode_metadata = {}

        def _save_episode_data(self, episode_buffer: dict) -> dict:
            return {**super()._save_episode_data(episode_buffer), **self._extra_episode_metadata}

    return ProvenanceLeRobotDataset


class LastEpisodeRow:
    """`meta.episodes` for an append: only the last episode's row (without its stats), found at its index.

    LeRobot 0.4.4 loads every row of `meta/episodes` when a dataset is opened, which makes an append cost
    O(dataset). Appending only reads the last row (where the next episode's frames and files start).
    """

    def __init__(self, root: Path, total_episodes: int):
        files = sorted((Path(root) / "meta" / "episodes").glob("*/*.parquet"))
        if not files:
            raise AdaDemoError(f"dataset {root} has no meta/episodes files; is it a LeRobot v3.0 dataset?")
        table = pq.read_table(files[-1])
        columns = [c for c in table.column_names if not c.startswith("stats/")]
        self.row = table.select(columns).slice(table.num_rows - 1).to_pylist()[0]
        self.total = total_episodes
        if self.row["episode_index"] != total_episodes - 1:
            raise AdaDemoError(
                f"dataset {root} is inconsistent: meta/info.json counts {total_episodes} episodes but the last "
                f"row of meta/episodes is episode {self.row['episode_index']}"
            )

    def __len__(self) -> int:
        return self.total

    def __getitem__(self, index: int) -> dict:
        if index not in (-1, self.total - 1):
            raise IndexError(f"only the last episode's metadata is loaded for appending, not episode {index}")
        return self.row


def _episode_rows_loaded_as_last_row_only(total_episodes: int):
    """Swap the `load_episodes` that LeRobotDataset's constructor calls for `LastEpisodeRow`, for one open."""
    import lerobot.datasets.lerobot_dataset as lerobot_dataset

    return temporarily_set(lerobot_dataset, "load_episodes", lambda root: LastEpisodeRow(root, total_episodes))


def atomic_write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _all_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def recover_interrupted_write(root: Path) -> int:
    """Undo a write that was killed before its commit. Returns the number of files removed."""
    txn_path = root / TXN_FILE
    if not txn_path.exists():
        return 0
    txn = json.loads(txn_path.read_text())
    keep = set(txn["files"])
    removed = 0
    for rel in _all_files(root):
        if rel not in keep and not rel.startswith(ADADEMO_DIR + "/"):
            (root / rel).unlink()
            removed += 1
    for rel in REWRITTEN_META:
        backup = root / TXN_BACKUP_DIR / Path(rel).name
        if backup.exists():
            shutil.copy2(backup, root / rel)
        elif rel not in keep and (root / rel).exists():
            (root / rel).unlink()
    for d in sorted((p for p in root.rglob("*") if p.is_dir()), reverse=True):
        if not any(d.iterdir()):
            d.rmdir()
    txn_path.unlink()
    shutil.rmtree(root / TXN_BACKUP_DIR, ignore_errors=True)
    log.warning("rolled back an interrupted write in %s (%d partial files removed)", root, removed)
    return removed


def _begin_write(root: Path) -> None:
    backup_dir = root / TXN_BACKUP_DIR
    shutil.rmtree(backup_dir, ignore_errors=True)
    backup_dir.mkdir(parents=True)
    for rel in REWRITTEN_META:
        if (root / rel).exists():
            shutil.copy2(root / rel, backup_dir / Path(rel).name)
    atomic_write_text(root / TXN_FILE, json.dumps({"files": _all_files(root)}))


def _commit_write(root: Path) -> None:
    (root / TXN_FILE).unlink()  # the commit point
    shutil.rmtree(root / TXN_BACKUP_DIR, ignore_errors=True)


def load_suite_config(root: Path) -> SuiteConfig:
    path = Path(root) / SUITE_FILE
    if not path.exists():
        raise AdaDemoError(
            f"{root} is not an adademo dataset (no {SUITE_FILE}); create one with "
            f"`adademo-collect --suite.tasks=... --dataset.repo_id=... --dataset.root=...`"
        )
    return SuiteConfig.from_dict(json.loads(path.read_text()))


def read_episode_metadata(root: str | Path) -> pd.DataFrame:
    """Per-episode metadata (task, length, `adademo/*` columns) as a table indexed by `episode_index`."""
    root = Path(root)
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        return pd.DataFrame(columns=["task", "length", *EPISODE_COLUMNS]).rename_axis("episode_index")
    wanted = ["episode_index", "tasks", "length", "dataset_from_index", "dataset_to_index"]
    tables = []
    for f in files:
        names = pq.read_schema(f).names
        tables.append(pq.read_table(f, columns=[c for c in wanted + list(EPISODE_COLUMNS) if c in names]).to_pandas())
    df = pd.concat(tables, ignore_index=True)
    missing = [c for c in EPISODE_COLUMNS if c not in df.columns]
    if missing:
        raise AdaDemoError(
            f"{root} has episodes without adademo metadata (missing {', '.join(missing)}); "
            "datasets for adademo are created with `adademo-collect`"
        )
    df["task"] = [t[0] if len(t) else "" for t in df.pop("tasks")]
    df[COL_INITIAL_STATE] = [np.asarray(v, dtype=np.float64) for v in df[COL_INITIAL_STATE]]
    return df.set_index("episode_index").sort_index()


class DemoDataset:
    """Create or append to an adademo LeRobot dataset; every append is one crash-safe transaction."""

    def __init__(self, repo_id: str, root: Path, suite_config: SuiteConfig):
        self.repo_id = repo_id
        self.root = Path(root)
        self.suite_config = suite_config

    @staticmethod
    def check_new_root(root: Path) -> None:
        root = Path(root)
        if root.exists() and any(root.iterdir()):
            raise AdaDemoError(
                f"dataset root {root} already exists; pass --resume=true to add episodes to it, "
                "or choose another --dataset.root"
            )
        parent = root
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise AdaDemoError(f"cannot write dataset root {root}: {parent} is not a writable folder")

    @classmethod
    def open(cls, repo_id: str, root: str | Path) -> DemoDataset:
        root = Path(root)
        if not (root / "meta" / "info.json").exists():
            raise AdaDemoError(f"no LeRobot dataset at {root} (missing meta/info.json)")
        if not os.access(root, os.W_OK):
            raise AdaDemoError(f"dataset root {root} is not writable")
        recover_interrupted_write(root)
        return cls(repo_id, root, load_suite_config(root))

    def episodes(self) -> pd.DataFrame:
        return read_episode_metadata(self.root)

    def append(
        self,
        suite: TaskSuite,
        demos: Iterable[Demonstration],
        round_index: int,
        source: str,
        collector: str,
    ) -> list[int]:
        """Write `demos` as new episodes in one transaction; returns their episode indices."""
        demos = list(demos)
        if not demos:
            return []
        dataset_cls = _provenance_dataset_class()
        creating = not (self.root / "meta" / "info.json").exists()
        if creating:
            # A brand-new dataset is built in a sibling folder and renamed into place once it is whole.
            write_root = self.root.with_name(f".{self.root.name}.adademo-creating")
            shutil.rmtree(write_root, ignore_errors=True)
            dataset = dataset_cls.create(
                repo_id=self.repo_id,
                fps=suite.fps,
                features=dataset_features(suite),
                root=write_root,
                robot_type=suite.name,
            )
            atomic_write_text(write_root / SUITE_FILE, suite.config.to_json())
        else:
            _begin_write(self.root)
            # Appending never reads frames: load only the last episode's frames and metadata row.
            total = json.loads((self.root / "meta" / "info.json").read_text())["total_episodes"]
            with _episode_rows_loaded_as_last_row_only(total):
                dataset = dataset_cls(self.repo_id, root=self.root, episodes=[total - 1])
        # One "Map" bar per episode otherwise; disabled after opening, whose loader turns the bars back on.
        datasets.disable_progress_bars()
        indices = []
        for demo in demos:
            for frame in demo.frames:
                dataset.add_frame({**frame, "task": demo.task})
            indices.append(dataset.meta.total_episodes)
            dataset.save_episode_with_metadata(
                {
                    COL_INITIAL_STATE: np.asarray(demo.initial_state, dtype=np.float64).tolist(),
                    COL_SEED: int(demo.seed),
                    COL_ROUND: int(round_index),
                    COL_SOURCE: source,
                    COL_COLLECTOR: collector,
                    COL_SUITE: suite.name,
                }
            )
        dataset.finalize()
        if creating:
            if self.root.exists():
                self.root.rmdir()  # an empty folder (anything else was refused by check_new_root)
            os.replace(write_root, self.root)
        else:
            _commit_write(self.root)
        return indices


class BufferedAppender:
    """Buffers demonstrations and commits them to the dataset every `commit_every` episodes."""

    def __init__(self, dataset: DemoDataset, suite: TaskSuite, round_index: int, source: str, collector: str,
                 commit_every: int):
        self.dataset, self.suite = dataset, suite
        self.round_index, self.source, self.collector = round_index, source, collector
        self.commit_every = max(1, commit_every)
        self.buffer: list[Demonstration] = []
        self.written: list[int] = []

    def add(self, demo: Demonstration) -> None:
        self.buffer.append(demo)
        if len(self.buffer) >= self.commit_every:
            self.flush()

    def flush(self) -> None:
        if self.buffer:
            self.written += self.dataset.append(
                self.suite, self.buffer, self.round_index, self.source, self.collector
            )
            self.buffer = []
