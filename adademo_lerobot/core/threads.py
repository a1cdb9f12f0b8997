"""torch's intra-op threads, never more than the CPUs this process may run on."""

from __future__ import annotations

import os
import sys

_told = False


def usable_cpus() -> int:
    """The CPUs this process may run on: fewer than the machine's under `taskset` or a container's cpuset."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def set_torch_threads(requested: int) -> int:
    """`torch.set_num_threads(requested)`, lowered to `usable_cpus()`, which it says once: more threads than CPUs
    wait for each other (an adademo-record round on one CPU took over 150 s with 2 threads, 28 s with 1).
    Returns the threads set."""
    global _told
    import torch

    threads = min(requested, usable_cpus())
    if threads < requested and not _told:
        _told = True
        print(
            f"note: {requested} torch threads on the {threads} CPU(s) this process may use (taskset, a cpuset) "
            f"would wait for each other: using {threads}",
            file=sys.stderr,
        )
    torch.set_num_threads(threads)
    return threads
