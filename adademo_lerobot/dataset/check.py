"""Refuse a damaged dataset before a command writes anything to it.

A disk that filled up or a copy that was killed leaves parquet files without their footer, or metadata that
disagrees with the data. Every command that writes checks first (cheap: parquet footers and metadata only, no
frame is decoded) and names the bad file in one line, so nothing is added to a dataset that cannot be read.
"""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.metadata import data_files, episode_files


def _footer(path: Path, root: Path) -> pq.FileMetaData:
    try:
        return pq.read_metadata(path)
    except (OSError, pa.ArrowException) as err:
        detail = " ".join(str(err).split())[:100]
        raise AdaDemoError(
            f"dataset {root} is damaged: {path.relative_to(root)} is not a complete parquet file ({detail}); "
            "restore the dataset from a copy (or the hub) before running adademo on it"
        ) from None


def check_dataset_integrity(root: str | Path) -> None:
    """Every data and meta/episodes parquet file is whole, and the episode index agrees with the data."""
    root = Path(root)
    info = read_info(root)
    damaged = f"dataset {root} is damaged"
    meta_files = episode_files(root)
    if info.get("total_episodes", 0) and not meta_files:
        raise AdaDemoError(
            f"{damaged}: meta/info.json counts {info['total_episodes']} episodes but meta/episodes "
            "has no files"
        )
    frames_in_data = sum(_footer(path, root).num_rows for path in data_files(root))
    rows = []
    for path in meta_files:
        _footer(path, root)
        table = pq.read_table(
            path, columns=["episode_index", "length", "dataset_from_index", "dataset_to_index"]
        )
        rows += table.to_pylist()
    rows.sort(key=lambda r: r["episode_index"])
    if [r["episode_index"] for r in rows] != list(range(len(rows))):
        raise AdaDemoError(f"{damaged}: meta/episodes does not hold episodes 0..{len(rows) - 1} exactly once")
    if len(rows) != info.get("total_episodes"):
        raise AdaDemoError(
            f"{damaged}: meta/info.json counts {info.get('total_episodes')} episodes but "
            f"meta/episodes holds {len(rows)}"
        )
    expected_start = 0
    for r in rows:
        if (
            r["dataset_from_index"] != expected_start
            or r["dataset_to_index"] - r["dataset_from_index"] != r["length"]
        ):
            raise AdaDemoError(
                f"{damaged}: episode {r['episode_index']}'s frame range in meta/episodes does not "
                "follow the previous episode's"
            )
        expected_start = r["dataset_to_index"]
    if expected_start != frames_in_data or frames_in_data != info.get("total_frames"):
        raise AdaDemoError(
            f"{damaged}: the data files hold {frames_in_data} frames, meta/episodes "
            f"{expected_start} and meta/info.json {info.get('total_frames')}"
        )
