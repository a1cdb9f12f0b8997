"""Measure the training step time of each preset in policies/ on this machine.

    python benchmarks/preset_step_time.py [--steps 30]

Collects small datasets (state, and pixels_state at 128x128 for the pixel presets), trains each preset for
--steps steps with adademo-train on the CPU (device forced to cpu) and reports the mean time of the last
two thirds of the steps (warm-up excluded). Writes benchmarks/results/preset_step_time.md.
"""

from __future__ import annotations

import argparse
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PRESETS = {
    "act_state_cpu": "state",
    "diffusion_state_cpu": "state",
    "act_pixels_gpu": "pixels_state",
    "diffusion_pixels_gpu": "pixels_state",
}


def collect(root: Path, obs_type: str) -> None:
    subprocess.run(
        [
            str(BIN / "adademo-collect"),
            "--suite.tasks=reach-v3,push-v3",
            "--episodes_per_task=3",
            f"--suite.obs_type={obs_type}",
            "--dataset.repo_id=local/bench",
            f"--dataset.root={root}",
        ],
        check=True,
        capture_output=True,
    )


def step_time(preset: str, dataset: Path, out: Path, steps: int) -> float:
    cmd = [
        str(BIN / "adademo-train"),
        f"--config_path={ROOT / 'policies' / (preset + '.yaml')}",
        "--dataset.repo_id=local/bench",
        f"--dataset.root={dataset}",
        f"--steps={steps}",
        "--policy.device=cpu",
        "--num_workers=0",
        f"--save_freq={steps}",
        f"--output_dir={out}",
        "--log_freq=1",
    ]
    if "pixels" in preset:
        cmd.append("--dataset.video_backend=pyav")
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    # LeRobot's MetricsTracker logs updt_s (update time) every step with --log_freq=1.
    times = [float(x) for x in re.findall(r"updt_s:([0-9.]+)", proc.stderr + proc.stdout)]
    warm = times[len(times) // 3 :]
    return 1000 * sum(warm) / len(warm)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=30)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        datasets = {}
        for obs_type in sorted(set(PRESETS.values())):
            datasets[obs_type] = Path(tmp) / obs_type
            collect(datasets[obs_type], obs_type)
        for preset, obs_type in PRESETS.items():
            ms = step_time(preset, datasets[obs_type], Path(tmp) / f"out-{preset}", args.steps)
            rows.append((preset, obs_type, ms))
            print(f"{preset:<24} {obs_type:<13} {ms:8.1f} ms/step", flush=True)
    lines = [
        "# Training step time of the presets in policies/",
        "",
        f"Command: `python benchmarks/preset_step_time.py --steps {args.steps}`; date {time.strftime('%Y-%m-%d')}; "
        f"machine: {platform.machine()}, 2-core CPU, torch threads 2, device forced to cpu.",
        "Datasets: 2 MetaWorld tasks x 3 scripted demos (state; pixels_state at 128x128). Mean update time of the",
        "last two thirds of the steps (LeRobot's `updt_s`: forward, backward, optimizer step).",
        "",
        "| preset | observations | ms per train step (CPU) |",
        "| --- | --- | --- |",
        *[f"| {p} | {o} | {ms:.0f} |" for p, o, ms in rows],
        "",
        "The *_gpu presets are meant for a GPU; their CPU time is listed for scale only.",
    ]
    out = ROOT / "benchmarks" / "results" / "preset_step_time.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
