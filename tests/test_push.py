"""adademo-push against a local test double of the hub (HF_ENDPOINT): files, card, private flag, branch, token;
and what was pushed coming back down with stock tools (LeRobotDataset(repo_id), snapshot_download)."""

import json
import os
import re
import secrets
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import BIN, file_digests, run_cli
from hub_double import HubDouble

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.loop.dataset_card import adademo_card_section

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
    run_cli(
        "adademo-expand",
        "--strategy.type=uniform",
        "--strategy.demos_per_task=1",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
    )
    return root


def hub_env(hub, tmp_path, token=TOKEN, **extra) -> dict[str, str]:
    """The environment of a child process that talks to the double: HF_ENDPOINT, its own HF_HOME, no saved login."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k
        not in (
            "HF_TOKEN",
            "HUGGING_FACE_HUB_TOKEN",
            "HF_TOKEN_PATH",
            "HF_HUB_OFFLINE",
            "HF_ENDPOINT",
            "HF_LEROBOT_HOME",
            "HF_HUB_CACHE",
            "HF_HUB_DISABLE_XET",
        )
    }
    env.update(
        HF_ENDPOINT=hub.url,
        HF_HOME=str(tmp_path / "hf_home"),
        HF_HUB_DISABLE_TELEMETRY="1",
        NO_PROXY="127.0.0.1,localhost",
        no_proxy="127.0.0.1,localhost",
        # huggingface_hub >= 1.0 uploads through Xet storage (a separate CAS server the hub hands out a
        # token for) whenever hf_xet is installed, and it is: LeRobot depends on it. The double implements
        # the hub's legacy LFS protocol instead (preupload, LFS batch with basic transfer, commit), which
        # huggingface_hub still uses when Xet is disabled. It reads this at import, hence the environment.
        HF_HUB_DISABLE_XET="1",
        **extra,
    )
    if token is not None:
        env["HF_TOKEN"] = token
    return env


def push(hub, tmp_path, *args, token=TOKEN) -> subprocess.CompletedProcess:
    """Run adademo-push as a user would, with the hub at the double and no saved login."""
    return subprocess.run(
        [str(BIN / "adademo-push"), *args],
        env=hub_env(hub, tmp_path, token=token),
        capture_output=True,
        text=True,
        timeout=300,
    )


def run_python(hub, tmp_path, script: str, **extra_env) -> dict:
    """Run `script` in a fresh Python (huggingface_hub at the double); it prints one JSON line last, returned."""
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        env=hub_env(hub, tmp_path, **extra_env),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert TOKEN not in proc.stdout + proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


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
    for required in (
        "meta/info.json",
        "meta/episodes/chunk-000/file-000.parquet",
        "data/chunk-000/file-000.parquet",
        "meta/adademo/suite.json",
        "meta/adademo/rounds.jsonl",
        "meta/adademo/round-001-evaluations.jsonl",
        "README.md",
    ):
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
    proc = push(
        hub,
        tmp_path,
        f"--dataset.root={expanded}",
        "--repo_id=alice/reach-push-public",
        "--branch=adademo-round-1",
    )
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
    proc = push(
        hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/wrong-token", token="hf_wrongToken"
    )
    assert_push_error(proc, "refused")
    assert ("dataset", "alice/wrong-token") not in hub.repos


def test_a_dataset_being_written_is_not_pushed_and_a_finished_rounds_journal_does_not_block(
    hub, expanded, tmp_path
):
    from adademo_lerobot.core.files import exclusive_use
    from adademo_lerobot.dataset.layout import ADADEMO_DIR
    from adademo_lerobot.loop.configs import PushConfig
    from adademo_lerobot.loop.push import validate

    with exclusive_use(expanded, "adademo-expand"):  # another command writes it now
        proc = push(hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/busy")
    assert_push_error(proc, "in use by another running adademo command")
    assert ("dataset", "alice/busy") not in hub.repos
    # Killed between round 1's ledger entry and the archiving of its journal: round 1 is finished.
    root = tmp_path / "ds"
    shutil.copytree(expanded, root)
    (root / ADADEMO_DIR / "journal-round-001.jsonl").write_text('{"type": "start"}\n')
    cfg = PushConfig(repo_id="alice/ds")
    cfg.dataset.root = str(root)
    assert validate(cfg) == root
    (root / ADADEMO_DIR / "journal-round-002.jsonl").write_text('{"type": "start"}\n')  # not in the ledger
    with pytest.raises(AdaDemoError, match="round 2 of .* is unfinished"):
        validate(cfg)


def test_card_for_many_tasks_has_one_row_per_round_and_task(expanded):
    card = adademo_card_section(expanded, max_task_columns=1)
    assert re.search(r"^\| 0 \| `initial` \| \+6 \| – \| 6 \|$", card, re.M), card
    assert re.search(r"^\| 1 \| `uniform` \(N=1\) \| \+2 \| – \| 8 \|$", card, re.M), card
    for row in (
        "| 0 | reach-v3 | +3 | – |",
        "| 0 | push-v3 | +3 | – |",
        "| 1 | reach-v3 | +1 | – |",
        "| 1 | push-v3 | +1 | – |",
    ):
        assert row in card


@pytest.mark.slow
def test_run_pushes_its_dataset_at_the_end(hub, tmp_path):
    """`adademo-run --push_to_hub=true` pushes the run's dataset, ledger included, once the run is complete."""
    env = hub_env(hub, tmp_path)
    proc = subprocess.run(
        [
            str(BIN / "adademo-run"),
            "--config_path=recipes/tiny.yaml",
            f"--run_dir={tmp_path / 'run'}",
            "--push_to_hub=true",
            "--hub_repo_id=alice/tiny-run",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert TOKEN not in proc.stdout + proc.stderr
    files = hub.repo("alice/tiny-run").files("main")
    assert {"meta/info.json", "meta/adademo/rounds.jsonl", "README.md"} <= set(files)
    assert "| 1 | `adademo`" in files["README.md"].decode()


def in_process_like_children(monkeypatch) -> None:
    """Calls made from this process (with `endpoint=hub.url`): huggingface_hub read its environment at import, so
    set what `hub_env` gives the children on its constants: no Xet (see `hub_env`), and no telemetry (it would
    fetch the agent-harness registry from huggingface.co, the constant endpoint of this process)."""
    from huggingface_hub import constants

    monkeypatch.setattr(constants, "HF_HUB_DISABLE_XET", True)
    monkeypatch.setattr(constants, "HF_HUB_DISABLE_TELEMETRY", True)


EPISODE_COLUMNS = ["episode_index", "tasks", "length", "adademo/round", "adademo/source", "adademo/seed"]


@pytest.mark.slow
def test_pushed_dataset_loads_back_with_stock_lerobot(hub, expanded, tmp_path):
    """`LeRobotDataset(repo_id)` (no root) downloads the pushed private dataset into a fresh HF_LEROBOT_HOME:
    the same episodes, every file byte for byte, `meta/adademo/` included."""
    proc = push(
        hub, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/reach-roundtrip", "--private=true"
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    hub.tree_page_size = 7  # the listing comes in pages, as on the hub for big datasets
    try:
        out = run_python(
            hub,
            tmp_path,
            f"""
            import json
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            cols = {EPISODE_COLUMNS!r}
            def episodes(ds):
                return {{c: [v if isinstance(v, (int, str)) else list(v) for v in ds.meta.episodes[c]] for c in cols}}
            remote = LeRobotDataset("alice/reach-roundtrip")
            local = LeRobotDataset("local/demo", root={str(expanded)!r})
            print(json.dumps({{"root": str(remote.root), "revision": remote.revision,
                               "frames": [remote.num_frames, local.num_frames],
                               "episodes": [episodes(remote), episodes(local)]}}))
        """,
            HF_LEROBOT_HOME=str(tmp_path / "lerobot_home"),
        )
    finally:
        hub.tree_page_size = HubDouble.tree_page_size
    assert hub.unknown == []
    assert any(
        "/api/datasets/alice/reach-roundtrip/tree/" in p and "cursor=" in p for _, p, _ in hub.requests
    )

    root = tmp_path / "lerobot_home"
    assert str(root) in out["root"]  # LeRobot's own hub cache under HF_LEROBOT_HOME
    assert out["revision"] == "v3.0"  # found through the codebase-version tag the push made
    remote_eps, local_eps = out["episodes"]
    assert remote_eps == local_eps and len(remote_eps["episode_index"]) == 8
    assert out["frames"][0] == out["frames"][1] > 0

    downloaded = file_digests(Path(out["root"]))
    assert {
        "meta/adademo/suite.json",
        "meta/adademo/rounds.jsonl",
        "meta/adademo/round-001-evaluations.jsonl",
        "README.md",
    } <= set(downloaded)
    local = file_digests(expanded)
    assert {rel: downloaded.get(rel) for rel in local} == local


@pytest.mark.slow
def test_checkpoint_round_trips_through_a_model_repo(hub, act_run, tmp_path, monkeypatch):
    """A LeRobot checkpoint folder uploaded to a model repo comes back with snapshot_download and loads with
    `load_policy`, weights identical."""
    from huggingface_hub import HfApi

    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    in_process_like_children(monkeypatch)
    api = HfApi(endpoint=hub.url, token=TOKEN)
    api.create_repo("alice/tiny-act", repo_type="model", private=True)
    api.upload_folder(repo_id="alice/tiny-act", folder_path=ckpt, repo_type="model")
    repo = hub.repo("alice/tiny-act", repo_type="model")
    assert repo.private is True
    assert {"config.json", "model.safetensors"} <= set(repo.files("main"))
    assert "model.safetensors" in {u.path for u in repo.uploads if u.lfs}  # weights went through LFS

    out = run_python(
        hub,
        tmp_path,
        f"""
        import json
        import torch
        from huggingface_hub import snapshot_download
        from adademo_lerobot.evaluation.policy import load_policy

        path = snapshot_download("alice/tiny-act")
        remote, local = load_policy(path), load_policy({str(ckpt)!r})
        a, b = remote.policy.state_dict(), local.policy.state_dict()
        same = a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        print(json.dumps({{"path": path, "type": remote.config.type, "same_weights": same,
                           "steps": [len(remote.preprocessor.steps), len(local.preprocessor.steps)]}}))
    """,
    )
    assert hub.unknown == []
    assert out["type"] == "act" and out["same_weights"] is True
    assert out["steps"][0] == out["steps"][1]
    assert str(tmp_path / "hf_home") in out["path"]
    downloaded = file_digests(Path(out["path"]))
    assert downloaded.pop(
        ".gitattributes"
    )  # the repo's own (the hub creates it), besides the checkpoint's files
    assert downloaded == file_digests(ckpt)


def test_download_errors_tell_repo_revision_and_file_apart(hub, tmp_path, monkeypatch):
    """Unknown repo, unknown revision, unknown file, and a private repo without the token, as the hub answers them."""
    from huggingface_hub import HfApi, hf_hub_download, snapshot_download
    from huggingface_hub.errors import EntryNotFoundError, RepositoryNotFoundError, RevisionNotFoundError

    in_process_like_children(monkeypatch)
    api = HfApi(endpoint=hub.url, token=TOKEN)
    api.create_repo("alice/errors", repo_type="dataset", private=True)
    api.upload_file(
        path_or_fileobj=b"hello\n", path_in_repo="hello.txt", repo_id="alice/errors", repo_type="dataset"
    )
    common = {"repo_type": "dataset", "endpoint": hub.url, "cache_dir": tmp_path / "cache"}

    path = snapshot_download("alice/errors", token=TOKEN, **common)
    assert str(tmp_path / "cache") in path and (Path(path) / "hello.txt").read_text() == "hello\n"
    with pytest.raises(RepositoryNotFoundError):
        snapshot_download("alice/no-such-repo", token=TOKEN, **common)
    with pytest.raises(RepositoryNotFoundError):  # it is a dataset repo, there is no model by that name
        snapshot_download("alice/errors", token=TOKEN, endpoint=hub.url, cache_dir=tmp_path / "cache")
    with pytest.raises(RevisionNotFoundError):
        snapshot_download("alice/errors", revision="no-such-branch", token=TOKEN, **common)
    with pytest.raises(EntryNotFoundError):
        hf_hub_download("alice/errors", "no-such-file.txt", token=TOKEN, **common)
    with pytest.raises(RepositoryNotFoundError):  # private: not found without the token
        snapshot_download(
            "alice/errors",
            token=False,
            repo_type="dataset",
            endpoint=hub.url,
            cache_dir=tmp_path / "anonymous",
        )
    assert hub.unknown == []


def test_card_validation_goes_to_the_endpoint_through_the_users_client(hub, monkeypatch):
    """During a push, `RepoCard.validate`'s hardcoded huggingface.co request goes to HF_ENDPOINT instead, made by
    the client the configured factory builds (its settings, and the proxies of the environment, kept)."""
    import httpx
    from huggingface_hub import constants, get_session, set_client_factory
    from huggingface_hub.utils import _http

    from adademo_lerobot.loop.push import HARDCODED_CARD_VALIDATION_URL, _card_validation_on_endpoint

    in_process_like_children(monkeypatch)
    monkeypatch.setattr(constants, "ENDPOINT", hub.url)
    monkeypatch.setenv("HTTPS_PROXY", "http://127.0.0.1:9")  # not used for the double (plain http)
    previous = _http._GLOBAL_CLIENT_FACTORY
    set_client_factory(
        lambda: httpx.Client(
            headers={"X-Users-Client": "1"},
            follow_redirects=True,
            timeout=None,
            event_hooks={"request": [_http.hf_request_event_hook]},
        )
    )
    try:
        with _card_validation_on_endpoint():
            session = get_session()
            assert session.headers.get("X-Users-Client") == "1"
            assert session._mounts  # HTTPS_PROXY honoured
            r = session.post(
                HARDCODED_CARD_VALIDATION_URL,
                headers={"Accept": "text/plain"},
                json={"repoType": "dataset", "content": "---\nlicense: mit\n---\ncard"},
            )
            assert r.status_code == 200 and r.json()["errors"] == []
        assert get_session().headers.get("X-Users-Client") == "1"  # the user's factory is back
    finally:
        set_client_factory(previous)
    assert hub.requests[-1] == ("POST", "/api/validate-yaml", 200)


def test_a_hub_that_does_not_answer_is_a_machine_failure_in_one_line(expanded, tmp_path):
    """Nothing listens at HF_ENDPOINT: exit 1 (the network, not the input; the same command pushes later), one
    `error:` line and nothing else on stderr (LeRobot's torchcodec warning once added ~90 lines on a machine
    without FFmpeg: the dataset is opened with the quietly chosen video backend)."""
    import socket
    from types import SimpleNamespace

    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        gone = SimpleNamespace(url=f"http://127.0.0.1:{probe.getsockname()[1]}")
    before = file_digests(expanded)
    proc = push(gone, tmp_path, f"--dataset.root={expanded}", "--repo_id=alice/offline")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr[-3000:]
    assert (
        lines[0].startswith(f"error: cannot reach the hub at {gone.url}")
        and "run the same command" in lines[0]
    )
    assert file_digests(expanded) == before
