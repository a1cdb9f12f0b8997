"""Training steps/s with batches from tensors in memory against LeRobot's per-sample loading, and the optimizer's
update one parameter tensor at a time (torch's default on CPU) against all at once (adademo-train's).

    python benchmarks/train_speed.py [--steps 200] [--updates 400]

The quickstart's initial dataset (4 MetaWorld tasks x 10 scripted demos, state observations) and its policy
preset (`policies/act_state_cpu.yaml`), trained with `--in_memory=true` and `--in_memory=false` in ABBA order;
steps/s from each run's own count, the data-loading share from adademo-train's log (`data_s` / step time).
Then the trained policy's own optimizer (LeRobot's ACT preset, AdamW over its parameter groups), stepped
`--updates` times on fixed gradients each way, in ABBA order, at the runs' 2 torch threads.
Writes benchmarks/results/train_speed.md.
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

import torch
from _common import RESULTS, collect, machine_line, train_act

from adademo_lerobot.loop.train import update_all_tensors_at_once


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


def update_ms(checkpoint: Path, at_once: bool, updates: int) -> float:
    """Milliseconds per optimizer step of the checkpoint's policy (LeRobot's preset for it), on fixed gradients."""
    from lerobot.policies.act.modeling_act import ACTPolicy

    torch.set_num_threads(2)
    policy = ACTPolicy.from_pretrained(checkpoint)
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    if at_once:
        update_all_tensors_at_once(optimizer)
    generator = torch.Generator().manual_seed(0)
    for p in policy.parameters():
        p.grad = torch.randn(p.shape, generator=generator) * 1e-3
    optimizer.step()  # the first step allocates the moments
    start = time.perf_counter()
    for _ in range(updates):
        optimizer.step()
    return 1000 * (time.perf_counter() - start) / updates


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--updates", type=int, default=400)
    args = parser.parse_args()
    results: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        dataset = collect(tmp / "ds", "reach-v3,push-v3,drawer-open-v3,pick-place-v3", 10)
        for k, in_memory in enumerate((True, False, False, True)):
            results[in_memory].append(train(dataset, tmp / f"run{k}", args.steps, in_memory))
            print(in_memory, results[in_memory][-1], flush=True)
        checkpoint = tmp / "run0" / "checkpoints" / "last" / "pretrained_model"
        updates: dict[bool, list[float]] = {True: [], False: []}
        for at_once in (False, True, True, False):
            updates[at_once].append(update_ms(checkpoint, at_once, args.updates))
            print("at once" if at_once else "one at a time", updates[at_once][-1], flush=True)
    med = {m: statistics.median(r for r, _ in v) for m, v in results.items()}
    share = {m: statistics.median(s for _, s in v) for m, v in results.items()}
    update = {m: statistics.median(v) for m, v in updates.items()}
    step_ms = 1000 / med[True]
    step_one = step_ms - update[True] + update[False]
    lines = [
        "# Training speed: batches from memory against LeRobot's per-sample loading; the optimizer's update",
        "",
        f"Command: `python benchmarks/train_speed.py --steps {args.steps} --updates {args.updates}`; "
        f"{machine_line()}.",
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
        "",
        "The optimizer's update (LeRobot's ACT preset: AdamW over the policy's parameter groups), "
        f"{args.updates} steps on fixed gradients each way in ABBA order, medians of 2; a training step is the "
        f"in-memory one above ({step_ms:.1f} ms, updating all at once), with the other update in its place:",
        "",
        "| update | ms per step | share of a training step |",
        "| --- | --- | --- |",
        f"| one tensor at a time (torch's default on CPU, `foreach=None`) | {update[False]:.2f} | "
        f"{100 * update[False] / step_one:.1f} % |",
        f"| all tensors at once (`foreach=True`, adademo-train's) | {update[True]:.2f} | "
        f"{100 * update[True] / step_ms:.1f} % |",
        "",
        f"All at once updates {update[False] / update[True]:.2f}x as fast: a training step "
        f"{step_one / step_ms:.3f}x as fast, with the same weights bit for bit (tests/test_train.py).",
    ]
    (RESULTS / "train_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
