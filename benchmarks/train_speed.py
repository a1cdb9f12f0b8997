"""Training steps/s with batches from tensors in memory against LeRobot's per-sample loading.

    python benchmarks/train_speed.py [--steps 200]

The quickstart's initial dataset (4 MetaWorld tasks x 10 scripted demos, state observations) and its policy
preset (`policies/act_state_cpu.yaml`), trained with `--in_memory=true` and `--in_memory=false` in ABBA order;
steps/s from each run's own count, the data-loading share from adademo-train's log (`data_s` / step time).
Writes benchmarks/results/train_speed.md.
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
from pathlib import Path

from _common import RESULTS, collect, machine_line, train_act


def train(dataset: Path, out: Path, steps: int, in_memory: bool) -> tuple[float, float]:
    proc = train_act(
        dataset,
        out,
        steps,
        f"--log_freq={steps // 2}",
        f"--in_memory={str(in_memory).lower()}",
        "--torch_threads=2",
    )
    rate = float(re.search(r"trained \d+ steps in [0-9.]+ s \(([0-9.]+) steps/s\)", proc.stdout).group(1))
    update, data = (float(x) for x in re.findall(r"updt_s:([0-9.]+) data_s:([0-9.]+)", proc.stdout)[-1])
    return rate, data / (update + data)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    results: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        dataset = collect(tmp / "ds", "reach-v3,push-v3,drawer-open-v3,pick-place-v3", 10)
        for k, in_memory in enumerate((True, False, False, True)):
            results[in_memory].append(train(dataset, tmp / f"run{k}", args.steps, in_memory))
            print(in_memory, results[in_memory][-1], flush=True)
    med = {m: statistics.median(r for r, _ in v) for m, v in results.items()}
    share = {m: statistics.median(s for _, s in v) for m, v in results.items()}
    lines = [
        "# Training speed: batches from memory against LeRobot's per-sample loading",
        "",
        f"Command: `python benchmarks/train_speed.py --steps {args.steps}`; {machine_line()}.",
        "Dataset: 4 MetaWorld tasks x 10 scripted demos (state observations); policy preset "
        "`policies/act_state_cpu.yaml` (small ACT, batch 32), 2 torch threads, trajectory sampler; runs in ABBA "
        "order, medians of 2 runs each.",
        "",
        "| loading | steps/s | data loading share of a step |",
        "| --- | --- | --- |",
        f"| in memory (`--in_memory=true`, default) | {med[True]:.2f} | {100 * share[True]:.1f} % |",
        f"| LeRobot's per-sample loading (`--in_memory=false`) | {med[False]:.2f} | {100 * share[False]:.1f} % |",
        "",
        f"In memory trains {med[True] / med[False]:.2f}x as many steps per second; the batches are the same samples "
        "(tests/test_train.py compares them key by key).",
    ]
    (RESULTS / "train_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
