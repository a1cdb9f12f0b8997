"""Wall time to append 10 episodes to adademo datasets of 20, 200 and 2,000 episodes.

    python benchmarks/append_scaling.py [--repeats 3]

Real scripted MetaWorld demonstrations (reach-v3, push-v3) are collected once and written again under new
seeds to grow the datasets; each measurement is one `DemoDataset.append` of 10 episodes (one transaction:
open, write, finalize, commit). Writes benchmarks/results/append_scaling.md.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from _common import RESULTS, grow_dataset, machine_line

SIZES = (20, 200, 2000)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in SIZES:
            ds, suite, collector, batch = grow_dataset(Path(tmp) / f"ds{size}", size)
            times = []
            for r in range(args.repeats):
                start = time.perf_counter()
                ds.append(suite, batch(10, 10**6 + 10 * r), 1, "bench", collector.name)
                times.append(time.perf_counter() - start)
            rows.append((size, statistics.median(times), times))
            print(
                f"{size} episodes: median {rows[-1][1]:.2f} s ({', '.join(f'{t:.2f}' for t in times)})",
                flush=True,
            )
    ratio = rows[-1][1] / rows[0][1]
    lines = [
        "# Append scaling: 10 new episodes into datasets of growing size",
        "",
        f"Command: `python benchmarks/append_scaling.py --repeats {args.repeats}`; {machine_line()}.",
        "State-only MetaWorld episodes (reach-v3/push-v3 scripted demos rewritten under new seeds).",
        "Each timing is one `DemoDataset.append` of 10 episodes: open the dataset, write, finalize, commit.",
        "",
        "| episodes in dataset | median seconds to append 10 | runs |",
        "| --- | --- | --- |",
        *[f"| {size} | {med:.2f} | {', '.join(f'{t:.2f}' for t in ts)} |" for size, med, ts in rows],
        "",
        f"Ratio 2,000 / 20 episodes: **{ratio:.2f}** (goal <= 1.2).",
    ]
    (RESULTS / "append_scaling.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
