"""The driver's CPU time per collected demonstration in a whole Ray round, with more workers than cores.

    python benchmarks/driver_cost.py [--workers 2 16] [--demos 10 60]

`benchmarks/loop_speed.py` times the driver's work per demonstration piece by piece, with 2 workers, and
`placement_cost.py` what submitting a unit costs; this checks the sum where it matters, on a whole round: an
`adademo-expand` round of the Uniform strategy (collection only) on MetaWorld MT10 from a committed round-0
dataset, on N Ray workers (`--ray.num_cpus_per_worker` set so that N fit on this machine: they share its cores,
which changes their speed, not what the driver does per demonstration). The driver's CPU time is its own process's
(`getrusage`, every thread; Ray's own processes and the workers excluded), read when the command ends. The round
runs twice per N, with few and with many demonstrations per task, alternating; the difference divided by the
difference in demonstrations is the driver's CPU per demonstration, start-up and the round's fixed costs cancelled.
Writes benchmarks/results/driver_cost.md. Needs an MT10 round 0 of the data-efficiency benchmark
(`--base OUT/seedS/base` of `data_efficiency.py arms --recipe recipes/budgeted_mt10.yaml --out OUT`).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import RESULTS, machine_line

from adademo_lerobot.dataset.info import read_info

RUN = """
import atexit, json, os, resource, sys, threading, time

TICK = os.sysconf("SC_CLK_TCK")
seen = {}  # thread id -> (name, CPU seconds so far): threads that end before the command are kept


def sample():
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        seen[tid] = (name, (int(fields[11]) + int(fields[12])) / TICK)


def keep_sampling():
    while True:
        sample()
        time.sleep(0.2)


def report():
    sample()
    usage = resource.getrusage(resource.RUSAGE_SELF)
    python_name = seen.get(str(os.getpid()), ("python", 0))[0]  # Python's threads keep the process's name
    in_python = sum(cpu for name, cpu in seen.values() if name == python_name)
    print("DRIVER_CPU " + json.dumps([usage.ru_utime + usage.ru_stime, in_python]), flush=True)


threading.Thread(target=keep_sampling, daemon=True).start()
atexit.register(report)
sys.argv[0] = "adademo-expand"
from adademo_lerobot.commands.expand import main
main()
"""


def one_round(base: Path, tmp: Path, workers: int, demos: int) -> tuple[float, float]:
    """The driver's CPU seconds in all, and in its Python threads (those that hold the GIL), for one round."""
    root = tmp / f"ds-{workers}-{demos}"
    shutil.rmtree(root, ignore_errors=True)
    shutil.copytree(base / "dataset", root)
    policy = base / "train" / "round-0" / "checkpoints" / "last" / "pretrained_model"
    args = [
        "--dataset.repo_id=local/mt10",
        f"--dataset.root={root}",
        f"--policy.path={policy}",
        "--strategy.type=uniform",
        f"--strategy.demos_per_task={demos}",
        "--executor=ray",
        f"--ray.num_workers={workers}",
        f"--ray.num_cpus_per_worker={min(1.0, 2 / workers):g}",
        "--torch_threads=1",
    ]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    out = subprocess.run([sys.executable, "-c", RUN, *args], capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise SystemExit(f"error: the round failed:\n{out.stderr[-2000:]}")
    shutil.rmtree(root, ignore_errors=True)
    line = next(x for x in out.stdout.splitlines() if x.startswith("DRIVER_CPU "))
    total, in_python = json.loads(line.split(" ", 1)[1])
    return float(total), float(in_python)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument(
        "--base",
        type=Path,
        required=True,
        help="a data_efficiency.py MT10 run's base folder (dataset, train)",
    )
    parser.add_argument("--workers", type=int, nargs="+", default=[2, 16])
    parser.add_argument("--demos", type=int, nargs=2, default=[10, 60], help="few and many demos per task")
    parser.add_argument("--repeats", type=int, default=1, help="measures per number of workers")
    args = parser.parse_args()
    few, many = args.demos
    tasks = int(read_info(args.base / "dataset")["total_tasks"])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for workers in args.workers:
                cpu = {few: one_round(args.base, Path(tmp), workers, few)}
                cpu[many] = one_round(args.base, Path(tmp), workers, many)
                added = (many - few) * tasks
                per_demo = [(cpu[many][k] - cpu[few][k]) / added * 1e3 for k in (0, 1)]
                rows.append((workers, cpu[few][0], cpu[many][0], *per_demo))
                print(f"{workers} workers: driver CPU {cpu[few]} / {cpu[many]} s -> {per_demo} ms per demo")
    rows.sort(key=lambda row: row[0])  # stable: each number of workers' measures in the order they ran
    lines = [
        "# The driver's CPU time per collected demonstration, on a whole Ray round",
        "",
        f"Command: `python benchmarks/driver_cost.py --base OUT/seed4/base --workers {' '.join(map(str, args.workers))} --demos {few} {many} --repeats {args.repeats}`; "
        f"{machine_line()}.",
        f"`adademo-expand` with the Uniform strategy (collection only, a few units per Ray call, workers write shards, commits journaled, merges "
        f"of 100 written by the workers) on MetaWorld MT10 from the data-efficiency benchmark's seed-4 round 0, "
        f"{few} and then {many} demonstrations per task; N Ray workers sharing the machine's 2 cores "
        "(`--ray.num_cpus_per_worker=2/N`). Driver CPU: its own process (user + system, all threads), read at exit.",
        "",
        f"| workers | driver CPU, {few} demos per task (s) | driver CPU, {many} per task (s) | "
        "driver CPU per added demonstration (ms) | of which in its Python threads (ms) |",
        "| --- | --- | --- | --- | --- |",
        *(f"| {w} | {a:.1f} | {b:.1f} | {d:.2f} | {p:.2f} |" for w, a, b, d, p in rows),
        "",
        f"Range over the {len(rows)} measures: {min(r[3] for r in rows):.2f}-{max(r[3] for r in rows):.2f} ms per "
        f"demonstration in all, {min(r[4] for r in rows):.2f}-{max(r[4] for r in rows):.2f} ms in its Python threads.",
        "",
        "Everything the driver does per demonstration is in the last two columns: choosing the worker and submitting the "
        "unit, fetching its result, the journal's lines, the commits and merges, the strategy's books and the "
        "progress bar (issue 39's goal: at most 1 ms). Its Python threads (the main thread and the tasks' threads, "
        "which take turns holding the GIL) are the part that cannot spread over more cores; the rest is Ray's own "
        "threads in the driver process (its core worker: submitting, receiving results, reference counting), "
        "sampled per thread from /proc every 0.2 s.",
    ]
    (RESULTS / "driver_cost.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS / 'driver_cost.md'}")


if __name__ == "__main__":
    main()
