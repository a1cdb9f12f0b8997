"""`--executor=ray` when the Ray node dies mid-round: every process of the command's local Ray (raylet, GCS,
actors, agents) is killed while the actors collect. The command must end within seconds (not after Ray's minute
of waiting for its GCS) with one `error:` line, leave a dataset stock LeRobot opens with exactly the committed
episodes, and the same command must then finish the round as an untouched one would."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import pytest
from conftest import BIN, run_cli
from test_executors import same_round

from adademo_lerobot.dataset.layout import TXN_FILE
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata

psutil = pytest.importorskip("psutil")
pytest.importorskip("ray")


def ray_processes(command: psutil.Process, temp_dir: str) -> list[psutil.Process]:
    """The local Ray node of `command`: its descendants that are Ray's, and any process of its session."""
    found = {}
    for p in command.children(recursive=True):
        try:
            if "ray" in " ".join(p.cmdline()) or p.name().startswith("ray::"):
                found[p.pid] = p
        except psutil.Error:
            pass
    for p in psutil.process_iter(["cmdline"]):
        if p.pid != command.pid and any(temp_dir in arg for arg in p.info["cmdline"] or ()):
            found[p.pid] = p
    return list(found.values())


def kill_node(command: psutil.Process, temp_dir: str) -> int:
    """SIGKILL every process of the node (again, for a worker the raylet started meanwhile); the count."""
    killed = set()
    for _ in range(3):
        victims = [p for p in ray_processes(command, temp_dir) if p.pid not in killed]
        if not victims:
            break
        for p in victims:
            try:
                p.send_signal(signal.SIGKILL)
                killed.add(p.pid)
            except psutil.Error:
                pass
        time.sleep(0.2)
    return len(killed)


def journaled_commits(root: Path) -> list[tuple[str, int]]:
    """The demonstrations a running round has committed to its journal (merged into the dataset later)."""
    journal = root / "meta" / "adademo" / "journal-round-001.jsonl"
    lines = journal.read_text().splitlines() if journal.exists() else []
    return [
        (task, seed)
        for line in lines
        if '"type": "shards"' in line
        for _, task, seed in json.loads(line)["shards"]
    ]


def merged_not_collected_again(root: Path, committed: list[tuple[str, int]]) -> None:
    """After the rerun, every demonstration the stopped run committed is in the dataset, collected once."""
    eps = read_episode_metadata(root)
    assert set(committed) <= set(zip(eps.task, eps["adademo/seed"], strict=True))
    demos = [(e["task"], e["seed"]) for e in read_round_evaluations(root, 1) if e["type"] == "demo"]
    assert all(demos.count(key) == 1 for key in committed)


def expand_args(dataset: Path, ckpt: Path) -> list[str]:
    """A round of adademo-expand on `dataset` that commits after every demonstration (a loss mid-round finds
    committed and uncommitted work)."""
    return [
        "--dataset.repo_id=local/demo",
        f"--dataset.root={dataset}",
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=6",
        "--eval.batch_size=3",
        "--commit_every=1",
    ]


@pytest.mark.slow
def test_a_lost_ray_node_ends_the_command_in_seconds_and_the_same_command_finishes_the_round(
    reach_push_dataset, act_run, tmp_path
):
    # A temp dir of its own (short: Ray's socket paths must fit 107 bytes) names the session's processes.
    temp_dir = tempfile.mkdtemp(prefix="adademo-ray-")
    try:
        lose_the_node_mid_round_then_rerun(reach_push_dataset, act_run, tmp_path, temp_dir)
    finally:
        shutil.rmtree(temp_dir, ignore_errors=True)


def lose_the_node_mid_round_then_rerun(reach_push_dataset, act_run, tmp_path, temp_dir: str) -> None:
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    root, reference = tmp_path / "lost", tmp_path / "reference"
    shutil.copytree(reach_push_dataset, root)
    shutil.copytree(reach_push_dataset, reference)

    args = [*expand_args(root, ckpt), "--executor=ray", "--ray.num_workers=2"]
    env = {**os.environ, "RAY_TMPDIR": temp_dir, "RAY_USAGE_STATS_ENABLED": "0"}
    before = read_episode_metadata(root)
    stderr_path = tmp_path / "stderr.txt"
    proc = None
    try:
        with stderr_path.open("w") as stderr:
            proc = subprocess.Popen(
                [str(BIN / "adademo-expand"), *args], stdout=subprocess.DEVNULL, stderr=stderr, env=env
            )
            command = psutil.Process(proc.pid)
            deadline = time.time() + 300
            # Two commits journaled while the actors still have the round's work.
            while len(journaled_commits(root)) < 2:
                assert time.time() < deadline and proc.poll() is None, (
                    "expand ended before it could be killed"
                )
                time.sleep(0.05)
            assert any(p.name().startswith("ray::EpisodeWorker") for p in ray_processes(command, temp_dir))
            killed_at = time.time()
            assert kill_node(command, temp_dir) >= 4  # GCS, raylet, the two actors, and Ray's helpers
            proc.wait(timeout=120)
            took = time.time() - killed_at
        err = stderr_path.read_text()
        lines = [line for line in err.splitlines() if line.strip()]
        assert proc.returncode == 1, err[-3000:]
        assert took < 20, f"the command took {took:.1f} s to end after the kill"
        assert lines[-1].startswith("error: lost the Ray cluster"), err[-3000:]
        assert "run the same command" in lines[-1] and "Traceback" not in err
        print(f"ended {took:.1f} s after the kill: {lines[-1]}")
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()

    # The dataset is as the last merge left it (the committed shards are merged when the round ends or resumes):
    # no write half done, stock LeRobot reads every episode.
    assert not (root / TXN_FILE).exists()  # the command let a merge in progress finish before it left
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    merged = read_episode_metadata(root)
    assert LeRobotDataset("local/demo", root=root).num_episodes == len(merged) >= len(before)
    kept = set(zip(merged.task, merged["adademo/seed"], strict=True))
    committed = journaled_commits(root)

    # The same command finishes the round: what an untouched round gives, with nothing lost or twice.
    rerun = subprocess.run(
        [str(BIN / "adademo-expand"), *args], capture_output=True, text=True, timeout=600, env=env
    )
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    eps = read_episode_metadata(root)
    assert kept <= set(zip(eps.task, eps["adademo/seed"], strict=True))
    new = eps[eps["adademo/round"] == 1]
    assert not new.duplicated(["task", "adademo/seed"]).any()  # no initial state twice
    assert sorted({r["round"] for r in read_ledger(root)}) == [1]
    merged_not_collected_again(root, committed)
    run_cli("adademo-expand", *expand_args(reference, ckpt))
    same_round(reference, root, 1)


@pytest.mark.slow
def test_a_lost_worker_node_of_a_two_node_cluster_ends_the_command_and_the_same_command_finishes_the_round(
    reach_push_dataset, act_run, tmp_path, monkeypatch
):
    """Two Ray nodes on this machine (one CPU each, one actor on each): shards are written on both nodes and merged
    by the driver; the worker node is then removed mid-round (its raylet and actor killed)."""
    from ray.cluster_utils import Cluster

    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    root, reference = tmp_path / "two-nodes", tmp_path / "reference"
    shutil.copytree(reach_push_dataset, root)
    shutil.copytree(reach_push_dataset, reference)
    args = expand_args(root, ckpt)
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        worker_node = cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        ray_args = ["--executor=ray", f"--ray.address={cluster.address}", "--ray.num_workers=2"]
        before = read_episode_metadata(root)
        stderr_path = tmp_path / "stderr.txt"
        with stderr_path.open("w") as stderr:
            proc = subprocess.Popen(
                [str(BIN / "adademo-expand"), *args, *ray_args], stdout=subprocess.DEVNULL, stderr=stderr
            )
            try:
                deadline = time.time() + 300
                # Two commits journaled (shards from both nodes) while the actors still have the round's work.
                while len(journaled_commits(root)) < 2:
                    assert time.time() < deadline and proc.poll() is None, (
                        "expand ended before the node was lost"
                    )
                    time.sleep(0.05)
                removed_at = time.time()
                cluster.remove_node(worker_node)
                proc.wait(timeout=120)
                took = time.time() - removed_at
            finally:
                if proc.poll() is None:
                    proc.kill()
        err = stderr_path.read_text()
        lines = [line for line in err.splitlines() if line.strip()]
        assert proc.returncode == 1, err[-3000:]
        assert took < 30, f"the command took {took:.1f} s to end after the node was lost"
        assert lines[-1].startswith(
            "error: lost the Ray cluster (its alive nodes have room for 1 of the 2"
        ), err[-3000:]
        assert "run the same command" in lines[-1] and "Traceback" not in err

        # The dataset is as the last merge left it, and stock LeRobot reads every episode.
        assert not (root / TXN_FILE).exists()
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        merged = read_episode_metadata(root)
        assert LeRobotDataset("local/demo", root=root).num_episodes == len(merged) >= len(before)
        committed = journaled_commits(root)

        # With a node back, the same command finishes the round as an untouched local round does.
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        rerun = subprocess.run(
            [str(BIN / "adademo-expand"), *args, *ray_args], capture_output=True, text=True, timeout=600
        )
        assert rerun.returncode == 0, rerun.stderr[-3000:]
        assert "written by the Ray workers, merged here" in rerun.stdout
        merged_not_collected_again(root, committed)
    finally:
        cluster.shutdown()
    assert not root.with_name(f".{root.name}.adademo-shards").exists()
    run_cli("adademo-expand", *expand_args(reference, ckpt))
    same_round(reference, root, 1)
