"""adademo-push against a local test double of the hub (HF_ENDPOINT): files, card, private flag, branch, token."""

import os
import re
import secrets
import shutil
import subprocess

import pytest

from adademo_lerobot.hub import adademo_card_section
from conftest import BIN, file_digests, run_cli
from hub_double import HubDouble

TOKEN = f"hf_adademoTest{secrets.token_hex(12)}"


@pytest.fixture(scope="module")
def hub():
    with HubDouble(token=TOKEN, user="alice") as double:
        yield double


@pytest.fixture(scope="module")
def expanded(reach_push_dataset, tmp_path_factory):
    """Round 0 (3 demos per task from adademo-collect) + round 1 (uniform, 1 demo per task)."""
    root = tmp_path_factory.mktemp("push") / "ds"
    shutil.copytree(reach_push_dataset, root)
    run_cli("adademo-expand", "--strategy=uniform", "--demos_per_task=1", "--dataset.repo_id=local/demo",
            f"--dataset.root={root}")
    return root


def push(hub, tmp_path, *args, token=TOKEN) -> subprocess.CompletedProcess:
    """Run adademo-push as a user would, with the hub at the double and no saved login."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("HF_TOKEN", "HUGGING_FACE_HUB_TOKEN", "HF_TOKEN_PATH", "HF_HUB_OFFLINE", "HF_ENDPOINT")}
    env.update(HF_ENDPOINT=hub.url, HF_HOME=str(tmp_path / "hf_home"), HF_HUB_DISABLE_TELEMETRY="1",
               NO_PROXY="127.0.0.1,localhost", no_proxy="127.0.0.1,localhost")
    if token is not None:
        env["HF_TOKEN"] = token
    return subprocess.run([str(BIN / "adademo-push"), *args], env=env, capture_output=True, text=True, timeout=300)


def assert_push_error(proc: subprocess.CompletedProcess, match: str) -> str:
    assert proc.returncode == 2, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error:") and match in last, last
    assert TOKEN not in proc.stdout + proc.stderr
    return last


def test_push_uploads_dataset_adademo_files_and_card(hub, expanded, tmp_path):
    before = file_digests(expanded)
    proc = push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/reach-push", "--private=true")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert TOKEN not in proc.stdout + proc.stderr
    assert f"{hub.url}/datasets/alice/reach-push" in proc.stdout.strip().splitlines()[-1]
    assert hub.unknown == []

    repo = hub.repo("alice/reach-push")
    assert repo.private is True
    arrived = {u.path for u in repo.uploads}
    for required in ("meta/info.json", "meta/episodes/chunk-000/file-000.parquet", "data/chunk-000/file-000.parquet",
                     "meta/adademo/suite.json", "meta/adademo/rounds.jsonl",
                     "meta/adademo/round-001-evaluations.jsonl", "README.md"):
        assert required in arrived, required
    files = repo.files("main")
    for rel in before:  # every file of the dataset, byte for byte; the local dataset is left untouched
        assert files[rel] == (expanded / rel).read_bytes(), rel
    assert file_digests(expanded) == before
    assert repo.tags["v3.0"] == repo.branches["main"]  # LeRobot's codebase-version tag

    card = files["README.md"].decode()
    front = card.split("---")[1]
    for tag in ("LeRobot", "adademo", "metaworld"):
        assert f"- {tag}\n" in front
    assert "data_files: data/*/*.parquet" in front  # LeRobot's card metadata is kept
    assert "`reach-v3`, `push-v3`" in card
    assert re.search(r"^\| 0 \| `initial` \| \+3 / – \| \+3 / – \| 6 \|$", card, re.M), card
    assert re.search(r"^\| 1 \| `uniform` \(N=1\) \| \+1 / – \| \+1 / – \| 8 \|$", card, re.M), card
    assert "`adademo/round`" in card and "`adademo/source`" in card
    assert '"total_episodes": 8' in card  # LeRobot's info.json section


def test_push_public_to_a_branch(hub, expanded, tmp_path):
    proc = push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/reach-push-public",
                "--branch=adademo-round-1")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith(f"{hub.url}/datasets/alice/reach-push-public/tree/adademo-round-1")
    repo = hub.repo("alice/reach-push-public")
    assert repo.private is False
    branch_files = repo.files("adademo-round-1")
    assert {"README.md", "meta/info.json", "meta/adademo/rounds.jsonl"} <= set(branch_files)
    assert set(repo.files("main")) == {".gitattributes"}
    assert {u.revision for u in repo.uploads} == {"adademo-round-1"}


def test_missing_token_is_refused(hub, expanded, tmp_path):
    proc = push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/no-token", token=None)
    last = assert_push_error(proc, "huggingface-cli login")
    assert "HF_TOKEN" in last
    assert ("dataset", "alice/no-token") not in hub.repos


def test_bad_repo_id_and_rejected_token(hub, expanded, tmp_path):
    requests_before = len(hub.requests)
    assert_push_error(push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=just-a-name"), "USER/NAME")
    assert len(hub.requests) == requests_before  # refused before any request
    proc = push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/wrong-token", token="hf_wrongToken")
    assert_push_error(proc, "refused")
    assert ("dataset", "alice/wrong-token") not in hub.repos


def test_card_for_many_tasks_has_one_row_per_round_and_task(expanded):
    card = adademo_card_section(expanded, max_task_columns=1)
    assert re.search(r"^\| 0 \| `initial` \| \+6 \| – \| 6 \|$", card, re.M), card
    assert re.search(r"^\| 1 \| `uniform` \(N=1\) \| \+2 \| – \| 8 \|$", card, re.M), card
    for row in ("| 0 | reach-v3 | +3 | – |", "| 0 | push-v3 | +3 | – |", "| 1 | reach-v3 | +1 | – |",
                "| 1 | push-v3 | +1 | – |"):
        assert row in card


def test_run_pushes_its_dataset_at_the_end(hub, tmp_path):
    """`adademo-run --push_to_hub=true` pushes the run's dataset, ledger included, once the run is complete."""
    env = {k: v for k, v in os.environ.items() if k not in ("HF_TOKEN", "HUGGING_FACE_HUB_TOKEN", "HF_ENDPOINT")}
    env.update(HF_ENDPOINT=hub.url, HF_HOME=str(tmp_path / "hf_home"), HF_TOKEN=TOKEN,
               NO_PROXY="127.0.0.1,localhost", no_proxy="127.0.0.1,localhost")
    proc = subprocess.run(
        [str(BIN / "adademo-run"), "--config_path=recipes/tiny.yaml", f"--run_dir={tmp_path / 'run'}",
         "--push_to_hub=true", "--hub_repo_id=alice/tiny-run"],
        env=env, capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert TOKEN not in proc.stdout + proc.stderr
    files = hub.repo("alice/tiny-run").files("main")
    assert {"meta/info.json", "meta/adademo/rounds.jsonl", "README.md"} <= set(files)
    assert "| 1 | `adademo`" in files["README.md"].decode()
