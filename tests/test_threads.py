"""torch's threads never exceed the CPUs a process may run on (taskset, a container's cpuset): with more, they wait
for each other (an adademo-record round on one CPU: over 150 s with 2 threads, 28 s with 1)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

SCRIPT = """
import json, os, sys
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # as `taskset -c N` starts a command
import torch
from adademo_lerobot.core.threads import set_torch_threads
first = set_torch_threads(int(sys.argv[1]))
second = set_torch_threads(int(sys.argv[1]))
print(json.dumps({"set": [first, second], "torch": torch.get_num_threads()}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform")
@pytest.mark.parametrize("requested", [1, 2])
def test_torch_threads_are_lowered_to_the_cpus_the_process_may_use_and_it_says_so_once(requested):
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(requested)], capture_output=True, text=True, check=True
    )
    assert json.loads(proc.stdout) == {"set": [1, 1], "torch": 1}
    notes = [line for line in proc.stderr.splitlines() if line.startswith("note:")]
    assert notes == (["note: 2 torch threads on the 1 CPU(s) this process may use (taskset, a cpuset) would "
                      "wait for each other: using 1"] if requested == 2 else [])  # fmt: skip
