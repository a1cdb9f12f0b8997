"""Training steps/s with AdaDemo's trajectory sampler vs the frame sampler (LeRobot's default behaviour).

    python benchmarks/sampler_overhead.py [--steps 300] [--repeats 6]

Same dataset (6 MetaWorld tasks x 10 scripted demos), same preset (`policies/act_state_cpu.yaml`), runs in
ABBA order (frame, trajectory, trajectory, frame, ...) so drift on the machine hits both alike; the figure is
the ratio of medians of the training loop's own rate (startup excluded). Writes
benchmarks/results/sampler_overhead.md.
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
from pathlib import Path

from _common import RESULTS, collect, machine_line, train_act

TASKS = "reach-v3,push-v3,pick-place-v3,drawer-open-v3,button-press-topdown-v3,peg-insert-side-v3"


def steps_per_second(dataset: Path, out: Path, sampler: str, steps: int) -> float:
    proc = train_act(dataset, out, steps, f"--sampler={sampler}", "--min_task_weight=0.05")
    steps_done, seconds = re.search(r"trained (\d+) steps in ([0-9.]+) s", proc.stdout).groups()
    return int(steps_done) / float(seconds)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=6)
    args = parser.parse_args()
    speeds: dict[str, list[float]] = {"frame": [], "trajectory": []}
    with tempfile.TemporaryDirectory() as tmp:
        dataset = collect(Path(tmp) / "ds", TASKS, 10)
        for r in range(args.repeats):
            for sampler in ("frame", "trajectory") if r % 2 == 0 else ("trajectory", "frame"):
                speeds[sampler].append(
                    steps_per_second(dataset, Path(tmp) / f"{sampler}{r}", sampler, args.steps)
                )
                print(sampler, speeds[sampler][-1], flush=True)
    frame, traj = statistics.median(speeds["frame"]), statistics.median(speeds["trajectory"])
    lines = [
        "# Sampler overhead: trajectory (AdaDemo C) vs frame (LeRobot's default) sampling",
        "",
        f"Command: `python benchmarks/sampler_overhead.py --steps {args.steps} --repeats {args.repeats}`; {machine_line()}.",
        "Dataset: 6 MetaWorld tasks x 10 scripted demos; preset `policies/act_state_cpu.yaml` (batch 32);",
        "steps/s of the training loop as printed by `adademo-train` (data loading included, startup not),",
        "runs in ABBA order.",
        "",
        "| sampler | steps/s per run | median |",
        "| --- | --- | --- |",
        f"| frame | {', '.join(f'{s:.2f}' for s in speeds['frame'])} | {frame:.2f} |",
        f"| trajectory | {', '.join(f'{s:.2f}' for s in speeds['trajectory'])} | {traj:.2f} |",
        "",
        f"Ratio of medians trajectory / frame: **{traj / frame:.3f}** (goal >= 0.97).",
    ]
    (RESULTS / "sampler_overhead.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
