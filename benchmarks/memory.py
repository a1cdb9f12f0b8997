"""Peak resident memory of adademo-expand and adademo-train on a 2,000-episode dataset.

    python benchmarks/memory.py

Peak RSS of each command's process tree, sampled every 50 ms with psutil. Writes benchmarks/results/memory.md.
"""

from __future__ import annotations

import subprocess
import tempfile
import time
from pathlib import Path

import psutil
from _common import BIN, RESULTS, ROOT, grow_dataset, machine_line, train_small_act


def peak_rss_mb(args: list[str]) -> tuple[float, float]:
    start = time.perf_counter()
    log = tempfile.TemporaryFile()  # noqa: SIM115  (not a pipe: a full pipe would block the child's bars)
    proc = subprocess.Popen([str(a) for a in args], stdout=subprocess.DEVNULL, stderr=log)
    ps, peak = psutil.Process(proc.pid), 0
    while proc.poll() is None:
        try:
            rss = ps.memory_info().rss + sum(c.memory_info().rss for c in ps.children(recursive=True))
            peak = max(peak, rss)
        except psutil.Error:
            pass
        time.sleep(0.05)
    if proc.returncode != 0:
        log.seek(0)
        raise RuntimeError(log.read().decode()[-2000:])
    return peak / 2**20, time.perf_counter() - start


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ds2000"
        grow_dataset(root, 2000)
        ckpt = train_small_act(root, Path(tmp) / "ckpt", steps=10)
        train_mb, train_s = peak_rss_mb(
            [
                BIN / "adademo-train",
                f"--config_path={ROOT / 'policies/act_state_cpu.yaml'}",
                "--dataset.repo_id=local/bench",
                f"--dataset.root={root}",
                "--steps=100",
                "--save_freq=100",
                f"--output_dir={Path(tmp) / 'train'}",
            ]
        )
        expand_mb, expand_s = peak_rss_mb(
            [
                BIN / "adademo-expand",
                "--dataset.repo_id=local/bench",
                f"--dataset.root={root}",
                f"--policy.path={ckpt}",
                "--strategy.type=adademo",
                "--strategy.target_successes=2",
                "--strategy.max_demos_per_task=5",
            ]
        )
    lines = [
        "# Peak memory on a 2,000-episode dataset",
        "",
        f"Command: `python benchmarks/memory.py`; {machine_line()}.",
        "Dataset: 2,000 state-only MetaWorld episodes (reach-v3/push-v3 scripted demos). Peak RSS of the command's",
        "process tree, sampled every 50 ms. Wall seconds are for orientation only: the machine may have been busy",
        "(speed figures are in loop_speed.md and preset_step_time.md).",
        "",
        "| command | peak RSS (MB) | wall s |",
        "| --- | --- | --- |",
        f"| adademo-train (act_state_cpu preset, 100 steps) | {train_mb:.0f} | {train_s:.0f} |",
        f"| adademo-expand (adademo, E=2, CAP=5) | {expand_mb:.0f} | {expand_s:.0f} |",
    ]
    (RESULTS / "memory.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
