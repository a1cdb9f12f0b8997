"""Will this machine train the same weights as the machines that ran the committed benchmarks? A few minutes to know.

    python benchmarks/kernel_reproducibility.py [--steps 150] [--repeats 3]

Trains the Adroit table's ACT (`recipes/adroit_table_ensembled.yaml`'s policy, one torch thread) on one fixed
synthetic batch for `--steps` steps under each setting of the numeric kernels, each in a new process (the settings
are read when torch loads), and prints the trained weights' digest and the milliseconds per step. Two machines whose
digests agree under the setting the benchmarks use (`data_efficiency.py --cpu_isa avx2`, "avx2 pin (benchmarks)")
should train the same policies from the same data (compare round 0 all the same); otherwise their runs pair only
with runs of their own kind (`data_efficiency.py report` checks round 0 per task before it pairs). Writes (or replaces) this CPU's section of
benchmarks/results/kernel_reproducibility.md, keeping the other machines' sections, and says which of their
digests this machine's equal.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import statistics
import subprocess
import sys
import time

from _common import AVX2_KERNELS, RESULTS, ROOT, avx2_kernels, machine_line

OUT = RESULTS / "kernel_reproducibility.md"
RECIPE = ROOT / "recipes" / "adroit_table_ensembled.yaml"
SETTINGS = {
    "native": {},
    "avx2 pin": AVX2_KERNELS,
    "avx2 pin (benchmarks)": avx2_kernels(),
    "avx2 pin + MKL_CBWR=AVX2": {**AVX2_KERNELS, "MKL_CBWR": "AVX2"},
    "avx2 pin + MKL_CBWR=COMPATIBLE": {**AVX2_KERNELS, "MKL_CBWR": "COMPATIBLE"},
}
HEADER = """# Do two machines train the same weights? Kernel settings and their digests

Command: `python benchmarks/kernel_reproducibility.py`, one section per CPU (a rerun replaces its own). Each row:
the Adroit table's ACT trained on one fixed synthetic batch, one torch thread, in a new process per setting; the
digest of the trained weights and milliseconds per step (median of interleaved runs). Equal digests under "avx2 pin
(benchmarks)" (what `data_efficiency.py` sets: on an AMD CPU also MKL's Intel path, `mkl_intel_path.c`) say that two machines should train the same policies from the same
data; `data_efficiency.py report` still compares their round 0 before it pairs their runs. "Same digest as" names
the machines above that trained the same digest under any of their settings (as measured when the row was written).
"""


def train_once(steps: int) -> None:
    """In the child process: train, then print the digest and the step time."""
    import torch
    import yaml
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    torch.set_num_threads(1)
    torch.manual_seed(0)
    fields = {k: v for k, v in yaml.safe_load(RECIPE.read_text())["train"]["policy"].items() if k != "type"}
    state, action = 46, 30  # hammer's observation; Adroit's hand and arm joints
    config = ACTConfig(
        **fields,
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (state,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (state,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (action,))},
    )
    policy = ACTPolicy(config)
    optimizer = torch.optim.AdamW(policy.parameters(), lr=config.optimizer_lr, foreach=True)
    g = torch.Generator().manual_seed(1)
    batch = {
        "observation.state": torch.randn(32, state, generator=g),
        "observation.environment_state": torch.randn(32, state, generator=g),
        "action": torch.randn(32, config.chunk_size, action, generator=g),
        "action_is_pad": torch.zeros(32, config.chunk_size, dtype=torch.bool),
    }
    started = time.perf_counter()
    for _ in range(steps):
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    ms = 1000 * (time.perf_counter() - started) / steps
    digest = hashlib.sha256(b"".join(p.detach().numpy().tobytes() for p in policy.parameters())).hexdigest()
    print(f"{digest[:16]} {ms:.1f}")


def measure(steps: int, repeats: int) -> list[tuple[str, str, float]]:
    """Each setting `repeats` times, the settings interleaved (ABCAB...): the median step time, and one digest (a
    setting whose digest changes between its runs is not deterministic: that is an error)."""
    digests, times = {}, {name: [] for name in SETTINGS}
    clean = {k: v for k, v in os.environ.items() if k not in {*AVX2_KERNELS, "MKL_CBWR", "LD_PRELOAD"}}
    for _ in range(repeats):
        for name, env in SETTINGS.items():
            proc = subprocess.run(
                [sys.executable, __file__, "--child", f"--steps={steps}"],
                env={**clean, **env, "OMP_NUM_THREADS": "1"},
                capture_output=True,
                text=True,
                check=True,
            )
            digest, ms = proc.stdout.split()[-2:]
            if digests.setdefault(name, digest) != digest:
                raise SystemExit(
                    f"error: {name} trained two different weights in two runs: not deterministic"
                )
            times[name].append(float(ms))
            print(f"{name}: {digest} {ms} ms/step", flush=True)
    return [(name, digests[name], statistics.median(times[name])) for name in SETTINGS]


def sections(text: str) -> dict[str, str]:
    """The committed sections by heading (a CPU's machine line)."""
    return {m.group(1): m.group(0) for m in re.finditer(r"^## (.+?)\n.*?(?=^## |\Z)", text, re.M | re.S)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3, help="runs of each setting, interleaved")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        train_once(args.steps)
        return
    rows = measure(args.steps, args.repeats)
    line = machine_line()
    cpu = line.split("machine: ", 1)[1].split(",")[0]
    others = {k: v for k, v in sections(OUT.read_text()).items() if k != cpu} if OUT.exists() else {}
    table = [
        "| setting | digest of the trained weights | ms per step | same digest as |",
        "| --- | --- | --- | --- |",
    ]
    for name, digest, ms in rows:
        same = [k for k, v in others.items() if f"| {digest} |" in v]  # under any of their settings
        table.append(f"| {name} | {digest} | {ms:.1f} | {'; '.join(same) or '-'} |")
    ms = {name: step_ms for name, _, step_ms in rows}
    speed = (
        f"Native kernels train {ms['avx2 pin (benchmarks)'] / ms['native']:.2f}x as fast as the benchmarks' pin here "
        "(one process at a time)."
    )
    mine = (
        f"## {cpu}\n\n{line}; {args.steps} steps, median of {args.repeats} interleaved runs.\n\n"
        + "\n".join(table)
        + f"\n\n{speed}\n\n"
    )
    OUT.write_text(HEADER + "\n" + "".join([*others.values(), mine]))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
