"""torch's threads never exceed the CPUs a process may run on (taskset, a container's cpuset): with more, they wait
for each other (an adademo-record round on one CPU: over 150 s with 2 threads, 28 s with 1)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

SCRIPT = """
import json, os
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # as `taskset -c N` starts a command
import torch
from adademo_lerobot.core.threads import set_torch_threads
print(json.dumps({"set": [set_torch_threads(n) for n in (1, 2, 2)], "torch": torch.get_num_threads()}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this platform")
def test_torch_threads_are_lowered_to_the_cpus_the_process_may_use_and_it_says_so_once():
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True)
    assert json.loads(proc.stdout) == {"set": [1, 1, 1], "torch": 1}
    notes = [line for line in proc.stderr.splitlines() if line.startswith("note:")]
    assert notes == [
        "note: 2 torch threads on the 1 CPU(s) this process may use (taskset, a cpuset) would wait for each "
        "other: using 1"
    ]  # asking for 1 says nothing; asking for 2 says it once
