"""The machine failing under a command (issue 34): a disk that fills in the middle of an append, Ctrl-C during a
commit, an exception inside LeRobot's own `finalize`, a disk that fills while a checkpoint is written. Each must
end in one `error:` line (no traceback), a dataset that stock LeRobot opens at once, unchanged, and a rerun that
completes the round exactly.

The full disk is real: a small tmpfs mounted for the test (root, as on the project's machines and in CI). Where
mounting is not allowed the tests are skipped, except in CI, which must run them.
"""

from __future__ import annotations

import errno
import json
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    BIN,
    TINY_ACT,
    file_digests,
    leave_free,
    lerobot_files,
    mount_small_disk,
    run_cli,
    stock_episodes,
)

from adademo_lerobot.dataset.layout import ADADEMO_DIR, TXN_FILE
from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata

UNIFORM = ["--strategy.type=uniform", "--strategy.demos_per_task=2"]


def dataset_files(root: Path) -> dict[str, str]:
    """The dataset's files and digests, without the round's journal (the resume log, appended as it runs)."""
    return {k: v for k, v in file_digests(root).items() if not Path(k).name.startswith("journal-round-")}


def round_episodes(root: Path, round_index: int) -> list[tuple]:
    """(task, seed, length, actions digest) of a round's episodes, in dataset order: what 'exactly' compares."""
    import hashlib

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    eps = read_episode_metadata(root)
    ds = LeRobotDataset("local/demo", root=root)
    out = []
    for _, row in eps[eps["adademo/round"] == round_index].iterrows():
        begin, end = int(row["dataset_from_index"]), int(row["dataset_to_index"])
        actions = np.stack([np.asarray(a) for a in ds.hf_dataset[begin:end]["action"]])
        out.append(
            (row.task, int(row["adademo/seed"]), end - begin, hashlib.sha256(actions.tobytes()).hexdigest())
        )
    assert len({(t, s) for t, s, *_ in out}) == len(out), "an initial state twice in a round"
    return out


def one_error_line(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("error: "), proc.stderr[-3000:]
    for needle in needles:
        assert needle in last, last
    return last


@pytest.fixture(scope="module")
def reference_round(reach_push_dataset, tmp_path_factory) -> list[tuple]:
    """Round 1 of Uniform (2 demos per task) on an untouched copy with plenty of space: what a rerun must equal."""
    root = tmp_path_factory.mktemp("reference") / "ds"
    shutil.copytree(reach_push_dataset, root)
    run_cli("adademo-expand", "--dataset.repo_id=local/demo", f"--dataset.root={root}", *UNIFORM)
    return round_episodes(root, 1)


def test_disk_full_in_the_middle_of_an_append_rolls_back_before_the_command_exits(
    reach_push_dataset, small_disk, reference_round
):
    root = small_disk / "ds"
    shutil.copytree(reach_push_dataset, root)
    before = dataset_files(root)
    # Room for the journal and the backups of the files an append rewrites, not for its new parquet files: the
    # write fails inside LeRobot's writer (the case).
    filler = leave_free(small_disk, 64 * 1024)
    args = ["--dataset.repo_id=local/demo", f"--dataset.root={root}", *UNIFORM]
    proc = run_cli("adademo-expand", *args, check=False)
    assert proc.returncode == 1, proc.stderr[-3000:]
    one_error_line(proc, "No space left on device", "rolled back", "free space and run the same command")
    # Right after the failed command, before any rerun: stock LeRobot opens it, byte for byte as before.
    assert dataset_files(root) == before
    assert stock_episodes(root) == 6
    assert not (root / TXN_FILE).exists()
    journal = root / ADADEMO_DIR / "journal-round-001.jsonl"
    assert all(json.loads(line) for line in journal.read_text().splitlines())  # no torn line either

    filler.unlink()  # space freed: the same command completes the round, exactly as with space from the start
    run_cli("adademo-expand", *args)
    assert round_episodes(root, 1) == reference_round
    assert stock_episodes(root) == 10
    assert sorted(r["round"] for r in read_ledger(root)) == [1, 1]


@pytest.mark.slow  # a local Ray (~10 s to start) and two runs of the round
@pytest.mark.parametrize(
    "free_kib, fails",
    [
        (60, "a Ray worker's collect failed"),  # the worker's first shard
        (200, "writing 4 episodes to the dataset"),  # the shards fit; the merge's files (written by a worker)
        (300, "writing 4 episodes to the dataset"),  # the merge's files fit; the driver's commit of them
    ],
)
def test_disk_full_during_a_ray_round_rolls_back_and_the_rerun_finishes_exactly(
    reach_push_dataset, small_disk, reference_round, free_kib: int, fails: str
):
    """The same round on a Ray worker, which writes what it collects as shards beside the dataset and the merge's
    files: wherever the disk fills (sizes found on this machine's tmpfs, 2026-12-05), one `error:` line, the
    dataset as it was, and the rerun gives the round as with room from the start."""
    root = small_disk / "ds"
    shutil.copytree(reach_push_dataset, root)
    before = dataset_files(root)
    filler = leave_free(small_disk, free_kib * 1024)
    args = ["--dataset.repo_id=local/demo", f"--dataset.root={root}", *UNIFORM]
    ray = ["--executor=ray", "--ray.num_workers=1"]
    proc = run_cli("adademo-expand", *args, *ray, check=False)
    assert proc.returncode == 1, proc.stderr[-3000:]
    last = one_error_line(proc, fails, "No space left on device", "free space and run the same command")
    assert "File " not in last and "\x1b" not in last, last  # no worker traceback, no terminal colours
    assert dataset_files(root) == before
    assert stock_episodes(root) == 6
    assert not (root / TXN_FILE).exists()

    filler.unlink()
    run_cli("adademo-expand", *args, *ray)
    assert round_episodes(root, 1) == reference_round
    assert stock_episodes(root) == 10


def test_disk_full_while_creating_a_dataset_leaves_nothing_half_made(small_disk):
    root = small_disk / "new"
    leave_free(small_disk, 48 * 1024)
    proc = run_cli(
        "adademo-collect",
        "--suite.tasks=reach-v3,push-v3",
        "--episodes_per_task=3",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        check=False,
    )
    assert proc.returncode == 1, proc.stderr[-3000:]
    one_error_line(proc, "No space left on device", "run the same command")
    assert not root.exists() or not any(root.iterdir())
    assert [p.name for p in small_disk.iterdir()] in (["filler"], ["filler", "new"])  # no half-made folder


def test_ctrl_c_during_a_commit_rolls_back_and_the_rerun_finishes_exactly(
    reach_push_dataset, tmp_path, reference_round
):
    """SIGINT while a commit writes (its transaction file exists), and again as it stops: the command rolls it back
    before it exits 130, with one line; the dataset then holds exactly the files it had before that commit."""
    args = [*UNIFORM, "--commit_every=1"]
    landed = 0
    for attempt in range(4):  # the signal may arrive just after a (fast) commit ended: then try again
        root = tmp_path / f"ds{attempt}"
        shutil.copytree(reach_push_dataset, root)
        proc = subprocess.Popen(
            [str(BIN / "adademo-expand"), "--dataset.repo_id=local/demo", f"--dataset.root={root}", *args],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            # Ctrl-C as in a terminal, even when the suite itself runs in the background (which ignores SIGINT).
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        txn, deadline = root / TXN_FILE, time.time() + 300
        listed = None
        while listed is None and proc.poll() is None and time.time() < deadline:
            try:
                listed = json.loads(txn.read_text())["files"]
            except (FileNotFoundError, json.JSONDecodeError):
                time.sleep(0.002)
        assert listed is not None, "no commit began"
        proc.send_signal(signal.SIGINT)
        time.sleep(0.005)
        # Ctrl-C again while it rolls back and leaves: no traceback, the rollback whole.
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
        if proc.returncode == 0:  # the last commit ended, and the command with it, before the signal was sent
            continue
        assert proc.returncode == 130, stderr[-3000:]
        assert "Traceback" not in stderr and "interrupted: rerun the same command" in stderr
        assert not txn.exists()
        stock_episodes(root)  # opens
        files = set(lerobot_files(root))
        listed = {k for k in listed if not k.startswith(ADADEMO_DIR + "/")}
        if files == listed:  # the commit was rolled back: exactly the files from before it
            landed += 1
            break
    assert landed, "the interrupt never landed inside a commit"
    run_cli("adademo-expand", "--dataset.repo_id=local/demo", f"--dataset.root={root}", *args)
    assert round_episodes(root, 1) == reference_round


def test_an_exception_inside_lerobots_finalize_is_rolled_back(reach_push_dataset, tmp_path, monkeypatch):
    """A fault injected where LeRobot's `finalize` closes its parquet writer (an I/O error), in this process."""
    import pyarrow.parquet as pq

    from adademo_lerobot.core.errors import MachineError
    from adademo_lerobot.dataset.store import DemoDataset
    from adademo_lerobot.loop.collect import collect_fresh
    from adademo_lerobot.suites import make_suite
    from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

    root = tmp_path / "ds"
    shutil.copytree(reach_push_dataset, root)
    before = dataset_files(root)
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    close = pq.ParquetWriter.close

    def failing_close(self):
        close(self)
        raise OSError(errno.EIO, "Input/output error (injected)")

    monkeypatch.setattr(pq.ParquetWriter, "close", failing_close)
    with pytest.raises(MachineError, match="Input/output error .*rolled back to its last commit"):
        collect_fresh(
            suite,
            DemoDataset.open("local/demo", root),
            {"reach-v3": 1},
            seed=5,
            round_index=1,
            source="uniform",
        )
    monkeypatch.undo()
    assert dataset_files(root) == before
    assert stock_episodes(root) == 6


def test_disk_full_while_writing_a_checkpoint_keeps_the_last_complete_one(reach_push_dataset, tmp_path):
    disk = tmp_path / "disk"
    mount_small_disk(disk, "800k")  # one checkpoint of this tiny ACT (~0.5 MB) fits, the second does not
    try:
        args = [
            "--dataset.repo_id=local/demo",
            f"--dataset.root={reach_push_dataset}",
            *TINY_ACT,
            "--steps=4",
            "--save_freq=2",
            f"--output_dir={disk / 'run'}",
        ]
        proc = run_cli("adademo-train", *args, check=False)
        assert proc.returncode == 1, proc.stderr[-3000:]
        one_error_line(proc, "checkpoint of step 4", "last complete checkpoint is step 2", "free space")
        checkpoints = disk / "run" / "checkpoints"
        assert sorted(p.name for p in checkpoints.iterdir()) == ["000002", "last"]  # no half checkpoint
        assert (checkpoints / "last").resolve().name == "000002"
        subprocess.run(["mount", "-o", "remount,size=4m", str(disk)], check=True)  # space freed
        run_cli("adademo-train", *args, "--resume=true")
        assert (checkpoints / "last").resolve().name == "000004"
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_killed_write_is_rolled_back_by_the_next_command_but_not_one_under_way(
    reach_push_dataset, tmp_path
):
    """A write a kill left half-done (its transaction file, a new file, a rewritten one) is rolled back by the next
    command that reads or checks the dataset (adademo-train, adademo-record, adademo-run's start), unless another
    command holds the dataset: then its write is under way, not killed, and the command is refused instead."""
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.core.files import exclusive_use
    from adademo_lerobot.dataset.store import REWRITTEN_META, _begin_write, recover_unless_in_use

    root = tmp_path / "ds"
    shutil.copytree(reach_push_dataset, root)
    before = dataset_files(root)
    _begin_write(root, list(REWRITTEN_META))  # as a write does before its first file
    stray = root / "data" / "chunk-000" / "file-999.parquet"
    stray.write_bytes(b"half a file")
    (root / "meta" / "info.json").write_text("{}")  # rewritten, not yet committed
    with exclusive_use(root, "adademo-expand"):  # the writer is alive
        with pytest.raises(AdaDemoError, match="in use by another running adademo command"):
            recover_unless_in_use(root, "adademo-train")
        train = [f"--dataset.root={root}", "--dataset.repo_id=local/demo", *TINY_ACT, "--steps=1"]
        proc = run_cli("adademo-train", *train, f"--output_dir={tmp_path / 'train'}", check=False)
        assert proc.returncode == 2 and "then rerun adademo-train" in proc.stderr.strip().splitlines()[-1]
        assert stray.exists() and (root / TXN_FILE).exists()
    recover_unless_in_use(root, "adademo-train")  # the writer was killed
    assert dataset_files(root) == before and not (root / TXN_FILE).exists()
    assert stock_episodes(root) == 6
