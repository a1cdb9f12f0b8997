"""Shared setup for the benchmark scripts: real datasets and a small trained ACT, made with our own commands."""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
RESULTS = ROOT / "benchmarks" / "results"


def sh(*args: str) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{args[0]} failed:\n{proc.stderr[-3000:]}")
    return proc


def collect(root: Path, tasks: str, per_task: int, seed: int = 0) -> Path:
    sh(
        BIN / "adademo-collect",
        f"--suite.tasks={tasks}",
        f"--episodes_per_task={per_task}",
        "--dataset.repo_id=local/bench",
        f"--dataset.root={root}",
        f"--seed={seed}",
    )
    return root


def train_act(dataset: Path, out: Path, steps: int, *extra: str) -> subprocess.CompletedProcess:
    """`adademo-train` of the small state ACT preset (`policies/act_state_cpu.yaml`); its output has the speed."""
    return sh(
        BIN / "adademo-train",
        f"--config_path={ROOT / 'policies' / 'act_state_cpu.yaml'}",
        "--dataset.repo_id=local/bench",
        f"--dataset.root={dataset}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        f"--output_dir={out}",
        *extra,
    )


def train_small_act(dataset: Path, out: Path, steps: int = 50) -> Path:
    train_act(dataset, out, steps)
    return out / "checkpoints" / "last" / "pretrained_model"


# Torch's, oneDNN's, MKL's, OpenBLAS's and NumPy's kernels as on an AVX2 machine: with these an AVX-512 AMD EPYC
# reproduced an AVX2 one's MT10 round 0 on seeds 0 and 1 (the same success on each task; unpinned: 82.6 % against
# 83.4 % on seed 0), but not on seed 2 (83.2 % against 84.6 %, 2026-12-04): it narrows the gap, it does not close
# it. Compare round 0 before pairing runs of two CPU types.
AVX2_KERNELS = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL",
}


MKL_INTEL_PATH_SOURCE = ROOT / "benchmarks" / "mkl_intel_path.c"


def mkl_intel_path() -> Path:
    """The shim that makes MKL take its Intel kernels on an AMD CPU (mkl_intel_path.c), built once with the
    machine's C compiler into ~/.cache/adademo-lerobot."""
    built = Path.home() / ".cache" / "adademo-lerobot" / "mkl_intel_path.so"
    if not built.exists() or built.stat().st_mtime < MKL_INTEL_PATH_SOURCE.stat().st_mtime:
        built.parent.mkdir(parents=True, exist_ok=True)
        tmp = built.with_suffix(".so.tmp")
        try:
            proc = subprocess.run(
                ["cc", "-shared", "-fPIC", "-O2", "-o", str(tmp), str(MKL_INTEL_PATH_SOURCE)],
                capture_output=True,
                text=True,
            )
        except FileNotFoundError:
            sys.exit(
                "error: on an AMD CPU the benchmarks' kernels need a C compiler to build MKL's Intel path "
                "(apt-get install gcc), or --cpu_isa avx2_own_mkl for MKL's own AMD kernels"
            )
        if proc.returncode != 0:
            sys.exit(f"error: cc could not build {MKL_INTEL_PATH_SOURCE.name}: {proc.stderr.strip()[-500:]}")
        tmp.rename(built)
    return built


def amd_cpu() -> bool:
    cpuinfo = Path("/proc/cpuinfo")
    return cpuinfo.exists() and "AuthenticAMD" in cpuinfo.read_text()


def avx2_kernels() -> dict[str, str]:
    """AVX2_KERNELS with MKL's reproducible AVX2 branch (MKL_CBWR=AVX2: fixed cache sizes and reduction order, the
    same bits on every Intel AVX2 CPU, MKL's documented guarantee), and on an AMD CPU the shim that makes MKL take
    that Intel branch there too (mkl_intel_path.c): an AVX-512 AMD EPYC then trains digest for digest what the
    Intel Xeon of 2026-12-07 trained, where without the shim no setting did, MKL's cross-vendor
    MKL_CBWR=COMPATIBLE included (kernel_reproducibility.md, 2026-12-08). On that Xeon the branch trains the same
    weights bit for bit as the plain pin."""
    kernels = {**AVX2_KERNELS, "MKL_CBWR": "AVX2"}
    if amd_cpu():
        kernels["LD_PRELOAD"] = " ".join(filter(None, [str(mkl_intel_path()), os.environ.get("LD_PRELOAD")]))
    return kernels


def machine_line() -> str:
    """Date, CPU, cores and the versions that decide the numbers."""
    import os
    from importlib import metadata

    info = Path("/proc/cpuinfo").read_text().splitlines()
    cpu = next(
        (line.split(":", 1)[1].strip() for line in info if line.startswith("model name")),
        platform.processor() or "unknown CPU",
    )
    # Two machines named "AMD EPYC" trained different policies from the same seed: the vector unit differs.
    flags = next((line.split(":", 1)[1].split() for line in info if line.startswith("flags")), [])
    cpu += " (AVX-512)" if "avx512f" in flags else " (AVX2)" if "avx2" in flags else ""
    if "avx512f" in flags and os.environ.get("ATEN_CPU_CAPABILITY") == AVX2_KERNELS["ATEN_CPU_CAPABILITY"]:
        cpu = cpu.replace("(AVX-512)", "(AVX-512, kernels pinned to AVX2)")
    if "mkl_intel_path" in os.environ.get("LD_PRELOAD", ""):
        cpu = cpu[:-1] + ", MKL's Intel path)" if cpu.endswith(")") else cpu + " (MKL's Intel path)"
    versions = ", ".join(f"{p} {metadata.version(p)}" for p in ("lerobot", "torch", "mujoco", "metaworld"))
    return (
        f"date {time.strftime('%Y-%m-%d')}; machine: {platform.machine()} {cpu}, {os.cpu_count()} CPU cores, "
        f"Python {platform.python_version()}, {versions}"
    )


def planner_config(fields: str, **extra):
    """The planner's config from "samples=16,horizon=8,..." (each value typed as its field's default)."""
    from adademo_lerobot.collectors import PlannerCollectorConfig

    defaults = PlannerCollectorConfig()

    def typed(name: str, text: str):
        default = getattr(defaults, name)
        if isinstance(default, bool):  # bool("false") is True
            return {"true": True, "false": False}[text.lower()]
        return text if default is None else type(default)(text)

    pairs = dict(kv.split("=") for kv in fields.split(",") if kv)
    return PlannerCollectorConfig(**extra, **{k: typed(k, v) for k, v in pairs.items()})


def grow_dataset(root: Path, episodes: int, tasks: str = "reach-v3,push-v3", unique: int = 10):
    """An adademo dataset of `episodes` real scripted demos (`unique` per task collected, then rewritten under
    new seeds). Returns (DemoDataset, suite, collector, demos)."""
    import dataclasses

    from adademo_lerobot.collectors import ScriptedCollectorConfig, make_collector
    from adademo_lerobot.core.seeds import derive_seed
    from adademo_lerobot.dataset.store import DemoDataset
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    suite = make_suite(MetaWorldSuiteConfig(tasks=tasks))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    demos = []
    for k in range(unique):
        for task in suite.tasks:
            s = derive_seed(0, task, k)
            demos.append(collector.collect(task, suite.sample_initial_state(task, s), s).demonstration)

    def batch(n: int, offset: int) -> list:
        return [dataclasses.replace(demos[i % len(demos)], seed=offset + i) for i in range(n)]

    ds = DemoDataset("local/bench", root, suite.config)
    written = 0
    while written < episodes:
        n = min(200, episodes - written)
        ds.append(suite, batch(n, written), 0, "initial", collector.name)
        written += n
    return ds, suite, collector, batch


class StepClock:
    """Times the simulator's own step inside our env (`env_class._raw_step`) while the loop runs, so loop / raw
    is the share of the loop's time the simulator gets (measurement only)."""

    def __init__(self, env_class: type):
        self.seconds, self.steps, stock = 0.0, 0, env_class._raw_step
        clock = self

        def timed(env, action):
            start = time.perf_counter()
            out = stock(env, action)
            clock.seconds += time.perf_counter() - start
            clock.steps += 1
            return out

        env_class._raw_step = timed

    def reset(self) -> None:
        self.seconds, self.steps = 0.0, 0


def loop_speed_args(episodes: int, episodes_help: str, demos_help: str) -> argparse.Namespace:
    """The flags of the loop-speed benchmarks (`--episodes`, `--demos`), then one process on one thread."""
    parser = argparse.ArgumentParser()
    parser.add_argument("--episodes", type=int, default=episodes, help=episodes_help)
    parser.add_argument("--demos", type=int, default=20, help=demos_help)
    args = parser.parse_args()
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)
    return args
