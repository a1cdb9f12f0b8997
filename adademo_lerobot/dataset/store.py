"""A standard LeRobot v3.0 dataset that remembers each episode's initial state and provenance.

Longer than 400 lines: the write transaction (backups, the signal-deferred commit, the rollback) and the one
class that uses it are kept together, so that every way to write the dataset is seen to go through it.

Our extras are extra columns in `meta/episodes` (`adademo/*`) and files under `meta/adademo/`; the format is
never forked, so stock `LeRobotDataset(repo_id, root=...)` opens every dataset written here.

New datasets are built in a sibling folder with `LeRobotDataset.create` and renamed into place. Appends use
`LeRobotDataset.resume` and are transactions: LeRobot writes a resumed session into new parquet/video files and
rewrites only `meta/info.json`, `meta/stats.json` and `meta/tasks.parquet`; we back those up (plus any
`meta/episodes` file we must give the adademo columns) and list the existing files before writing, and delete
the list once `finalize()` has written the parquet footers.

A write that fails (a full disk, an I/O error, Ctrl-C, an exception of LeRobot's or ours) is rolled back before
the exception leaves `append`: the files it created are removed and the backups renamed back over the files it
rewrote. Rolling back only deletes and renames, so it needs no free space. A write killed outright (`kill -9`,
power loss) is rolled back the same way on the next open. So the dataset on disk always holds exactly the
committed episodes, and stock LeRobot opens it right after any failure.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from adademo_lerobot.core.episodes import Demonstration
from adademo_lerobot.core.errors import AdaDemoError, MachineError, machine_cause
from adademo_lerobot.core.files import (
    COMMIT_LOCK,
    atomic_write_json,
    atomic_write_text,
    check_writable_location,
    exclusive_use,
)
from adademo_lerobot.core.interrupts import signals_deferred
from adademo_lerobot.core.patching import temporarily_set
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.interventions import (
    apply_provenance,
    carried_frame_values,
    check_writable_features,
    intervention_flags,
)
from adademo_lerobot.dataset.layout import (
    ADADEMO_DIR,
    COL_COLLECTOR,
    COL_INITIAL_STATE,
    COL_ROUND,
    COL_SEED,
    COL_SOURCE,
    COL_START_STATE,
    COL_START_STEP,
    COL_SUITE,
    EPISODE_COLUMNS,
    SUITE_FILE,
    TXN_BACKUP_DIR,
    TXN_FILE,
    episode_provenance,
)
from adademo_lerobot.dataset.metadata import (
    ENV_STATE_KEY,
    episode_files,
    has_dataset,
    imported_episode_values,
    load_suite_config,
    read_episode_metadata,
)
from adademo_lerobot.dataset.video import video_backend
from adademo_lerobot.suites import SuiteConfig, TaskSuite

REWRITTEN_META = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")

log = logging.getLogger(__name__)


def _all_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def recover_unless_in_use(root: Path, command: str) -> None:
    """`recover_interrupted_write` for a command that does not hold the dataset itself (training reads it; record
    and run check it first): refused in one line while another command holds it, whose write under way is not a
    killed one to roll back."""
    if (Path(root) / TXN_FILE).exists():
        with exclusive_use(root, command):
            recover_interrupted_write(root)


def recover_interrupted_write(root: Path, failed_here: bool = False) -> int:
    """Undo a write that was killed before its commit (`failed_here`: that failed in this process, whose error
    says so). Returns the number of files removed."""
    root = Path(root)
    txn_path = root / TXN_FILE
    if not txn_path.exists():
        return 0
    txn = json.loads(txn_path.read_text())
    if "creates" in txn:  # a write that named its new files in advance (a merge of shards): only those go
        created = [root / rel for rel in txn["creates"]]
        removed = _remove_created(created)
        keep = None
    else:
        keep = set(txn["files"])
        removed = 0
        for rel in _all_files(root):
            if rel not in keep and not rel.startswith(ADADEMO_DIR + "/"):
                (root / rel).unlink()
                removed += 1
    flat = "backed_up" not in txn  # written by adademo-lerobot 0.1, which kept flat backups
    for rel in txn.get("backed_up", REWRITTEN_META):
        backup = root / TXN_BACKUP_DIR / (Path(rel).name if flat else rel)
        if backup.exists():  # a rename, not a copy: restoring must work on a full disk
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(backup, root / rel)
        elif keep is not None and rel not in keep and (root / rel).exists():
            (root / rel).unlink()
        # else: restored by an earlier, interrupted rollback (the rename is done)
    folders = {p.parent for p in created} if keep is None else (p for p in root.rglob("*") if p.is_dir())
    for d in sorted(folders, key=lambda p: len(p.parts), reverse=True):
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    txn_path.unlink()
    shutil.rmtree(root / TXN_BACKUP_DIR, ignore_errors=True)
    if not failed_here:
        log.warning("rolled back an interrupted write in %s (%d partial files removed)", root, removed)
    return removed


def _remove_created(paths: list[Path]) -> int:
    """A rolled-back write's new files (and the temporary files their atomic writes may have left)."""
    removed = 0
    for path in paths:
        for candidate in (path, path.with_name(f".{path.name}.tmp")):
            if candidate.exists():
                candidate.unlink()
                removed += 1
    return removed


def _begin_write(root: Path, backed_up: list[str], creates: list[str] | None = None) -> None:
    """Back up the files the write will rewrite and list the files it will create (`creates`, when the write
    knows them in advance: O(write) instead of listing the whole dataset) or else every file, then mark the write
    as begun. If this fails (no space for the backups), nothing of the dataset has changed yet: the backups are
    removed and it raises."""
    backup_dir = root / TXN_BACKUP_DIR
    shutil.rmtree(backup_dir, ignore_errors=True)
    try:
        for rel in backed_up:
            if (root / rel).exists():
                (backup_dir / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(root / rel, backup_dir / rel)
        listed = {"files": _all_files(root)} if creates is None else {"creates": creates}
        atomic_write_json(root / TXN_FILE, {**listed, "backed_up": backed_up}, indent=None)
    except BaseException:
        shutil.rmtree(backup_dir, ignore_errors=True)
        raise


def _commit_write(root: Path) -> None:
    (root / TXN_FILE).unlink()  # the commit point
    shutil.rmtree(root / TXN_BACKUP_DIR, ignore_errors=True)


def _remove_empty_folders(folder: Path) -> None:
    """LeRobot's writer leaves `images/<camera>/` behind, empty, once a resumed session's frames are encoded to
    video (stock lerobot-record's datasets have none): remove the empty folders, nothing else."""
    if not folder.is_dir():
        return
    for path in sorted(folder.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        if path.is_dir() and not any(path.iterdir()):
            path.rmdir()
    if not any(folder.iterdir()):
        folder.rmdir()


def _abandon(dataset) -> None:
    """Close a failed write's LeRobot writers without finishing them: their files are about to be rolled back,
    and LeRobot's clean-up at garbage collection (`finalize` in `__del__`) must not write metadata again."""
    writer, meta = getattr(dataset, "writer", None), dataset.meta
    meta._metadata_buffer.clear()
    for obj, names in (
        (writer, ("image_writer", "_streaming_encoder", "_pq_writer")),
        (meta, ("_pq_writer",)),
    ):
        for name in names:
            handle = getattr(obj, name, None)
            if handle is None:
                continue
            with contextlib.suppress(Exception):  # a full disk may refuse even the close
                if name == "image_writer":
                    handle.stop()
                else:
                    handle.close()
            setattr(obj, name, None)
    for obj in (writer, meta):
        if obj is not None:
            obj._finalized = True
    dataset._is_finalized = True


def write_failure(err: BaseException, root: Path, what: str) -> MachineError:
    """The one-line error for a write that failed and was rolled back."""
    cause, first = machine_cause(err)
    return MachineError(
        f"writing {what} to the dataset {root} failed ({cause}); the dataset was rolled back to its last commit "
        f"and opens as before: {first}run the same command to resume"
    )


def _episode_files_without_columns(root: Path) -> list[Path]:
    return [f for f in episode_files(root) if not set(EPISODE_COLUMNS) <= set(pq.read_schema(f).names)]


# Arrow types of our episode columns, as our writer's features declare them.
EPISODE_COLUMN_TYPES = {
    COL_INITIAL_STATE: pa.list_(pa.float64()),
    COL_SEED: pa.int64(),
    COL_ROUND: pa.int64(),
    COL_SOURCE: pa.string(),
    COL_COLLECTOR: pa.string(),
    COL_SUITE: pa.string(),
    COL_START_STEP: pa.int64(),
    COL_START_STATE: pa.list_(pa.float64()),
}


def _add_adademo_columns(path: Path, suite_name: str, flags: np.ndarray | None = None) -> None:
    """Give the episodes of one meta/episodes file the adademo columns (imported: round 0, no initial state;
    with LeRobot's `intervention` flags, corrections and the policy's own episodes, as they are read), so that
    files written before and after share one schema, which stock LeRobot needs to load them."""
    table = pq.read_table(path)
    n = table.num_rows
    columns = {col: [value] * n for col, value in imported_episode_values(suite_name).items()}
    if flags is not None:
        rows = table.select(["dataset_from_index", "dataset_to_index"]).to_pandas()
        rows = rows.assign(**{c: columns[c] for c in (COL_SOURCE, COL_START_STEP, COL_COLLECTOR)})
        apply_provenance(rows, flags, np.ones(n, dtype=bool))
        columns |= {c: rows[c].tolist() for c in (COL_SOURCE, COL_START_STEP, COL_COLLECTOR)}
    for name, values in columns.items():
        if name not in table.column_names:
            table = table.append_column(name, pa.array(values, EPISODE_COLUMN_TYPES[name]))
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(table, tmp, compression="snappy")
    os.replace(tmp, path)


def _saving_extra_columns(dataset, columns: dict):
    """While the next episode is saved, merge `columns` into its meta/episodes row.

    LeRobot has no parameter for extra per-episode metadata on `LeRobotDataset.save_episode`; its metadata
    layer's public `save_episode(..., episode_metadata)` merges a dict into the row, so we add ours there."""
    meta = dataset.meta
    save = type(meta).save_episode

    def save_with_columns(episode_index, episode_length, episode_tasks, episode_stats, episode_metadata):
        save(
            meta, episode_index, episode_length, episode_tasks, episode_stats, {**episode_metadata, **columns}
        )

    return temporarily_set(meta, "save_episode", save_with_columns)


class LastEpisodeRow:
    """`meta.episodes` for an append: only the last episode's row (without its stats), found at its index.

    `LeRobotDataset.resume` loads every row of `meta/episodes` (through a `datasets` cache), which makes an append
    cost O(dataset); appending reads only the last row (where the next episode's frames and files start)."""

    def __init__(self, root: Path, total_episodes: int):
        files = episode_files(root)
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


def _last_episode_row_only(root: Path):
    """While a dataset is opened for appending, LeRobot's metadata loader reads only the last episode row."""
    import lerobot.datasets.dataset_metadata as dataset_metadata

    if not hasattr(dataset_metadata, "load_episodes"):  # a silent no-op swap would hide a slow append
        raise RuntimeError("lerobot.datasets.dataset_metadata.load_episodes is gone: update adademo's append")
    total = json.loads((root / "meta" / "info.json").read_text())["total_episodes"]
    return temporarily_set(dataset_metadata, "load_episodes", lambda _: LastEpisodeRow(root, total))


def _no_image_embedding_without_images():
    """LeRobot runs `embed_images` on every saved episode: a row-by-row `datasets.map` that rewrites each row's
    table to embed image bytes. Without image features it changes nothing but costs ~2/3 of an append (state
    datasets); skip it then (the written files are the same, tests/test_collect.py compares them)."""
    import datasets
    import lerobot.datasets.dataset_writer as dataset_writer

    stock = dataset_writer.embed_images

    def embed_images(dataset):
        if any(isinstance(ft, datasets.Image) for ft in dataset.features.values()):
            return stock(dataset)
        return dataset

    return temporarily_set(dataset_writer, "embed_images", embed_images)


def provenance_columns(
    demo: Demonstration, round_index: int, source: str, collector: str, producer: str
) -> dict:
    """Our columns of a demonstration's episode row (`dataset/layout.py`)."""
    source, collector = episode_provenance(source, collector, demo.is_correction, demo.by_policy)
    return {
        COL_INITIAL_STATE: np.asarray(demo.initial_state, dtype=np.float64).tolist(),
        COL_SEED: int(demo.seed),
        COL_ROUND: int(round_index),
        COL_SOURCE: source,
        COL_COLLECTOR: collector,
        COL_SUITE: producer,
        COL_START_STEP: int(demo.start_step),
        # Never an empty list: LeRobot's writer would type a batch of those as list<null>, which stock LeRobot
        # then cannot load beside files of list<double>.
        COL_START_STATE: np.asarray(
            demo.initial_state if demo.start_state is None else demo.start_state, np.float64
        ).tolist(),
    }


class DemoDataset:
    """Create or append to an adademo LeRobot dataset; every append is one crash-safe transaction."""

    def __init__(self, repo_id: str, root: Path, suite_config: SuiteConfig | None):
        self.repo_id = repo_id
        self.root = Path(root)
        self.suite_config = suite_config  # None: a dataset recorded on a robot (adademo-record)

    @staticmethod
    def check_new_root(root: Path) -> None:
        root = Path(root)
        check_writable_location(root, "dataset root")  # a file there, or a folder we cannot write
        if root.exists() and any(root.iterdir()):
            raise AdaDemoError(
                f"dataset root {root} already exists; pass --resume=true to add episodes to it, "
                "or choose another --dataset.root"
            )

    @classmethod
    def open(cls, repo_id: str, root: str | Path, suite_override: SuiteConfig | None = None) -> DemoDataset:
        """An existing dataset, for appending: a write a kill left half-done is rolled back first."""
        root = Path(root)
        if not has_dataset(root):
            raise AdaDemoError(f"no LeRobot dataset at {root} (missing meta/info.json)")
        if not os.access(root, os.W_OK):
            raise AdaDemoError(f"dataset root {root} is not writable")
        recover_interrupted_write(root)
        return cls(repo_id, root, load_suite_config(root, suite_override))

    @classmethod
    def open_recorded(cls, repo_id: str, root: str | Path) -> DemoDataset:
        """An existing dataset recorded on a robot (no suite), for appending what adademo-record records."""
        root = Path(root)
        if not os.access(root, os.W_OK):
            raise AdaDemoError(f"dataset root {root} is not writable")
        recover_interrupted_write(root)
        return cls(repo_id, root, None)

    def episodes(self) -> pd.DataFrame:
        return read_episode_metadata(self.root)

    def append(
        self, suite: TaskSuite, demos: Iterable[Demonstration], round_index: int, source: str, collector: str
    ) -> list[int]:
        """Write `demos` as new episodes in one transaction (creating the dataset on first use); returns their
        episode indices."""
        return self._append(list(demos), round_index, source, collector, suite.name, suite)

    def append_recorded(
        self, robot_type: str, demos: Iterable[Demonstration], round_index: int, source: str, collector: str
    ) -> list[int]:
        """Write episodes recorded on a robot (the dataset exists) in one transaction; returns their indices."""
        return self._append(list(demos), round_index, source, collector, robot_type, None)

    def can_merge(self, suite: TaskSuite) -> bool:
        """Whether workers' shards (written with the suite's features) can be merged here: the dataset exists,
        every episode file has our columns, and its features are exactly the suite's (none carried, e.g. a DAgger
        dataset's `intervention`). Otherwise demonstrations come back as frames and are appended."""
        from lerobot.utils.constants import DEFAULT_FEATURES

        if not has_dataset(self.root) or _episode_files_without_columns(self.root):
            return False
        found = read_info(self.root).get("features", {})
        expected = dataset_features(suite)
        ours = {k: ft for k, ft in found.items() if k not in DEFAULT_FEATURES}
        return ours.keys() == expected.keys() and all(
            tuple(ours[k]["shape"]) == tuple(ft["shape"]) and ours[k]["dtype"] == ft["dtype"]
            for k, ft in expected.items()
        )

    @contextlib.contextmanager
    def writing(self, what: str, creates: list[str], rewrites: list[str]):
        """A write of files into the existing dataset (e.g. a merge of workers' shards, `dataset/shards.py`) as
        one transaction: the block may create the files `creates` and rewrite those of `rewrites` (paths
        relative to the root); if it fails it is rolled back before the exception leaves (a machine failure then
        says what was being written)."""
        with COMMIT_LOCK:
            try:
                _begin_write(self.root, rewrites, creates)  # if this fails, it has changed nothing
                yield
            except BaseException as err:
                with signals_deferred():
                    recover_interrupted_write(self.root, failed_here=True)
                if isinstance(err, Exception) and not isinstance(err, AdaDemoError):
                    raise write_failure(err, self.root, what) from err
                raise
            _commit_write(self.root)

    def _append(
        self,
        demos: list[Demonstration],
        round_index: int,
        source: str,
        collector: str,
        producer: str,
        suite: TaskSuite | None,
    ) -> list[int]:
        if not demos:
            return []
        with COMMIT_LOCK:  # a command that must leave at once waits for this commit (or its rollback)
            return self._write(demos, round_index, source, collector, producer, suite)

    def _write(self, demos, round_index, source, collector, producer, suite) -> list[int]:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        creating = not has_dataset(self.root)
        if creating and suite is None:
            raise AdaDemoError(f"no LeRobot dataset at {self.root} to add the recorded episodes to")
        what = f"{len(demos)} episode{'s' * (len(demos) != 1)}"
        write_root = self.root.with_name(f".{self.root.name}.adademo-creating") if creating else self.root
        dataset = None
        try:
            if creating:
                # A brand-new dataset is built in a sibling folder and renamed into place once it is whole.
                shutil.rmtree(write_root, ignore_errors=True)
                dataset = LeRobotDataset.create(
                    repo_id=self.repo_id,
                    fps=suite.fps,
                    features=dataset_features(suite),
                    root=write_root,
                    robot_type=suite.name,
                    video_backend=video_backend(),
                )
                atomic_write_text(write_root / SUITE_FILE, suite.config.to_json())
            else:
                # Before anything changes: a feature LeRobot's writer wants in every frame and we cannot fill.
                if demos[0].frames:
                    check_writable_features(self.root, demos[0].frames[0], "adademo")
                adopt = _episode_files_without_columns(self.root)
                suite_missing = suite is not None and not (self.root / SUITE_FILE).exists()
                rewritten = [*REWRITTEN_META, *(str(f.relative_to(self.root)) for f in adopt)]
                _begin_write(self.root, rewritten + [SUITE_FILE] * suite_missing)
                flags = intervention_flags(self.root) if adopt else None
                for path in adopt:  # episodes that arrived without our columns (LeRobot's tools drop them)
                    _add_adademo_columns(path, producer, flags)
                if suite_missing:  # LeRobot's tools copy no extra files: keep the (rebuilt) suite from now on
                    atomic_write_text(self.root / SUITE_FILE, suite.config.to_json())
                with _last_episode_row_only(self.root):
                    dataset = LeRobotDataset.resume(
                        self.repo_id, root=self.root, video_backend=video_backend()
                    )
            indices = self._write_episodes(dataset, demos, round_index, source, collector, producer)
        except BaseException as err:
            with signals_deferred():
                if dataset is not None:
                    _abandon(dataset)
                if creating:
                    shutil.rmtree(write_root, ignore_errors=True)
                else:
                    recover_interrupted_write(self.root, failed_here=True)
            if isinstance(err, Exception) and not isinstance(err, AdaDemoError):
                raise write_failure(err, self.root, what) from err
            raise
        with signals_deferred():  # between the rmdir and the rename, Ctrl-C would leave no dataset at all
            if creating:
                if self.root.exists():
                    self.root.rmdir()  # an empty folder (anything else was refused by check_new_root)
                os.replace(write_root, self.root)
            else:
                _commit_write(self.root)
        _remove_empty_folders(self.root / "images")
        return indices

    @staticmethod
    def _write_episodes(dataset, demos, round_index, source, collector, producer) -> list[int]:
        import datasets

        from adademo_lerobot.dataset.stats import lerobot_stats_by_value_bins

        # One "Map" bar per episode otherwise; disabled after opening, whose loader turns the bars back on.
        datasets.disable_progress_bars()
        indices = []
        # Features we do not produce but carry, e.g. `intervention`: False only in a kept policy rollout.
        carried = {
            by_policy: carried_frame_values(dataset.meta.features, by_policy) for by_policy in (False, True)
        }
        # A robot view's dataset (`--suite.view=robot`) has no environment_state: the expert read it, the
        # dataset keeps what the robot records.
        unrecorded = {ENV_STATE_KEY} - set(dataset.meta.features)
        with _no_image_embedding_without_images(), lerobot_stats_by_value_bins():
            for demo in demos:
                for frame in demo.frames:
                    kept = {k: v for k, v in frame.items() if k not in unrecorded} if unrecorded else frame
                    dataset.add_frame({**carried[demo.by_policy], **kept, "task": demo.task})
                indices.append(dataset.meta.total_episodes)
                columns = provenance_columns(demo, round_index, source, collector, producer)
                with _saving_extra_columns(dataset, columns):
                    dataset.save_episode()
            dataset.finalize()
        return indices
