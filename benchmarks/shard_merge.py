"""The driver's time per demonstration: today's append (frames through LeRobot's writer on the driver) against
merging shards the workers wrote (`--ray.worker_writes`, `dataset/shards.py`). Same demonstrations, two copies of
one dataset, one process; each configuration checks that both give the same episodes and frames, and that stock
LeRobot opens the merged dataset.

    python benchmarks/shard_merge.py [--demos 40]

Writes benchmarks/results/shard_merge.md: per commit size (state observations; and a 64x64 camera), the driver's
milliseconds per demonstration for an append and for a merge, and the worker's for writing the shard.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from _common import RESULTS, machine_line

import adademo_lerobot.commands  # noqa: F401  (a program: the GL backend for the camera rows, as the commands')

CONFIGS = [("state", 1), ("state", 10), ("state", 50), ("camera 64x64", 10)]


def collect_demos(suite, n: int) -> list:
    from adademo_lerobot.collectors import make_collector
    from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig

    collector = make_collector(ScriptedCollectorConfig(), suite)
    return [
        collector.collect(t, suite.sample_initial_state(t, i), i).demonstration
        for i in range(n)
        for t in [suite.tasks[i % len(suite.tasks)]]
    ]


def measure(suite, demos: list, batch: int, tmp: Path) -> dict:
    from adademo_lerobot.dataset.metadata import read_episode_metadata
    from adademo_lerobot.dataset.shard_merge import ShardMerger
    from adademo_lerobot.dataset.shards import write_shard
    from adademo_lerobot.dataset.store import DemoDataset

    base, a, b = tmp / "base", tmp / "append", tmp / "merge"
    DemoDataset("local/x", base, suite.config).append(suite, demos[:2], 0, "initial", "scripted")
    shutil.copytree(base, a)
    shutil.copytree(base, b)
    rest = demos[2:]

    start = time.perf_counter()
    dataset = DemoDataset.open("local/x", a)
    for k in range(0, len(rest), batch):
        dataset.append(suite, rest[k : k + batch], 1, "budgeted", "scripted")
    append_s = time.perf_counter() - start

    start = time.perf_counter()
    shards = [write_shard(tmp / "shards", suite, d) for d in rest]
    worker_s = time.perf_counter() - start
    start = time.perf_counter()
    merger = ShardMerger(DemoDataset.open("local/x", b))  # as a round's appender holds one
    for k in range(0, len(shards), batch):
        merger.merge(shards[k : k + batch], 1, "budgeted", "scripted")
    merge_s = time.perf_counter() - start

    ea, eb = read_episode_metadata(a), read_episode_metadata(b)
    cols = ["task", "length", "adademo/seed", "adademo/round", "adademo/source", "adademo/collector"]
    pd.testing.assert_frame_equal(ea[cols], eb[cols])
    da = pd.concat(pq.read_table(p).to_pandas() for p in sorted((a / "data").rglob("*.parquet")))
    db = pd.concat(pq.read_table(p).to_pandas() for p in sorted((b / "data").rglob("*.parquet")))
    for col in da.columns:
        np.testing.assert_array_equal(np.stack(da[col].to_numpy()), np.stack(db[col].to_numpy()))
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    stock = LeRobotDataset("local/x", root=b, video_backend="pyav")
    assert stock.num_episodes == len(demos) and stock.num_frames == len(da)
    stock[len(stock) - 1]
    n = len(rest)
    return {
        "append_ms": 1000 * append_s / n,
        "worker_ms": 1000 * worker_s / n,
        "merge_ms": 1000 * merge_s / n,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--demos", type=int, default=40, help="demonstrations per configuration (after 2 to start)"
    )
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

    rows = []
    for kind, batch in CONFIGS:
        obs = {"obs_type": "pixels_state", "image_size": 64} if kind != "state" else {}
        suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3", **obs).build()
        demos = collect_demos(suite, args.demos + 2)
        with tempfile.TemporaryDirectory() as tmp:
            result = measure(suite, demos, batch, Path(tmp))
        print(kind, batch, {k: round(v, 1) for k, v in result.items()}, flush=True)
        rows.append((kind, batch, result))
    lines = [
        "# Writing where the episodes are: the driver's time per demonstration",
        "",
        f"`python benchmarks/shard_merge.py --demos {args.demos}`; {machine_line()}. One process, torch 1 thread;",
        "MetaWorld reach-v3 and push-v3, scripted demonstrations (~50-100 frames), appended to / merged into a",
        "2-episode dataset in commits of the given size. Each row checked: the same episodes and frames either way,",
        "and stock LeRobot opens the merged dataset.",
        "",
        "| observations | commit size | driver: append (ms/demo) | driver: merge (ms/demo) | merge / append | "
        "worker: write its shard (ms/demo) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for kind, batch, r in rows:
        lines.append(
            f"| {kind} | {batch} | {r['append_ms']:.1f} | {r['merge_ms']:.1f} | "
            f"{r['merge_ms'] / r['append_ms']:.2f} | {r['worker_ms']:.1f} |"
        )
    (RESULTS / "shard_merge.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS / 'shard_merge.md'}")


if __name__ == "__main__":
    main()
