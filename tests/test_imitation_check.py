"""benchmarks/imitation_check.py: its bad input (the score it prints is tested in test_imitability.py)."""

import subprocess
import sys
from pathlib import Path

from conftest import load_benchmark

imitation_check = load_benchmark("imitation_check")


def test_a_folder_that_is_not_a_dataset_or_run_is_one_error_line(tmp_path):
    script = Path(imitation_check.__file__)
    for flag, says in (("--dataset", "is not a LeRobot dataset"), ("--run_dir", "is not a run folder")):
        proc = subprocess.run(
            [sys.executable, str(script), flag, str(tmp_path)], capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 2 and says in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
