"""adademo-run and adademo-report end to end on the tiny recipe: real collection, training, rollouts."""

import json
import signal
import subprocess
import time

from adademo_lerobot.dataset.store import read_episode_metadata
from adademo_lerobot.evaluation import evaluation_seeds
from adademo_lerobot.ledger import read_ledger
from conftest import BIN, assert_cli_error, run_cli

STAGES = ["collect", "train-0", "eval-0", "expand-1", "train-1", "eval-1"]
PNG = b"\x89PNG\r\n\x1a\n"


def test_tiny_recipe_end_to_end_with_report(tmp_path):
    run_dir = tmp_path / "adademo"
    proc = run_cli("adademo-run", "--config_path=recipes/tiny.yaml", f"--run_dir={run_dir}")
    assert "run complete" in proc.stdout
    state = json.loads((run_dir / "run_state.json").read_text())
    assert list(state["done"]) == STAGES
    eps = read_episode_metadata(run_dir / "dataset")
    assert set(eps["adademo/round"]) == {0, 1} and (eps[eps["adademo/round"] == 1]["adademo/source"] == "adademo").all()
    assert [r["round"] for r in read_ledger(run_dir / "dataset")] == [1, 1]
    for i in (0, 1):  # the fixed evaluation set: same seeds every round, never used for expansion
        import pandas as pd

        records = pd.read_parquet(run_dir / "eval" / f"round-{i:03d}" / "eval_episodes.parquet")
        for task in ("reach-v3", "push-v3"):
            assert list(records[records.task == task].seed) == evaluation_seeds(100, task, 2)
        assert not set(records.seed) & set(eps["adademo/seed"])
    assert (run_dir / "train" / "round-1" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").exists()
    report = (run_dir / "report" / "report.md").read_text()
    assert "round 0: SR % (demos)" in report and "round 1: SR % (demos)" in report and "reach-v3" in report
    assert "| 1 | adademo |" in report  # the ledger's round
    for png in ("success_vs_demos.png", "eval_cost.png", "allocation_adademo.png", "success_adademo.png"):
        assert (run_dir / "report" / png).read_bytes()[:8] == PNG

    # A second arm and a comparison report.
    uniform = tmp_path / "uniform"
    run_cli("adademo-run", "--config_path=recipes/tiny.yaml", f"--run_dir={uniform}", "--strategy=uniform",
            "--train.sampler=task")
    out = tmp_path / "compare"
    run_cli("adademo-report", f"--run_dir={run_dir}", "--compare", str(uniform), f"--output_dir={out}")
    compared = (out / "report.md").read_text()
    assert "| adademo | adademo + trajectory sampler |" in compared and "| uniform | uniform + task sampler |" in compared


def test_kill_midway_then_rerun_finishes_without_redoing_stages(tmp_path):
    run_dir = tmp_path / "killed"
    args = ["--config_path=recipes/tiny.yaml", f"--run_dir={run_dir}", "--train.steps=40", "--train.save_freq=10"]
    proc = subprocess.Popen([str(BIN / "adademo-run"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    state_path = run_dir / "run_state.json"
    deadline = time.time() + 600
    while True:
        assert time.time() < deadline and proc.poll() is None, "the run ended before it could be killed"
        if state_path.exists() and "eval-0" in json.loads(state_path.read_text())["done"]:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = json.loads(state_path.read_text())["done"]
    rerun = run_cli("adademo-run", *args)
    for stage in before:
        assert f"[done] {stage}" in rerun.stdout
    after = json.loads(state_path.read_text())["done"]
    assert list(after) == STAGES
    assert all(after[s] == before[s] for s in before)  # finished stages were not redone
    assert (run_dir / "report" / "report.md").exists()


def test_run_bad_input(tmp_path):
    assert_cli_error("adademo-run", "--config_path=recipes/tiny.yaml", match="--run_dir")
    assert_cli_error("adademo-run", "--config_path=recipes/tiny.yaml", f"--run_dir={tmp_path / 'r'}",
                     "--strategy=random", match="strategy")
    assert_cli_error("adademo-run", "--config_path=recipes/tiny.yaml", f"--run_dir={tmp_path / 'r'}",
                     "--target_successes=[0]", match="target_successes")
    assert_cli_error("adademo-report", f"--run_dir={tmp_path}", match="run_state.json")
    assert not (tmp_path / "r").exists()
