"""Inputs that are there but are not what they should be, and machines that are not there: a damaged checkpoint,
a recipe that is not a mapping of settings, a run folder's state edited by hand, a file where a folder goes, a
device torch does not have, a Ray head nothing listens at. Each is one `error:` line, exit 2, before anything is
written or run (each once ended in a traceback, a wasted evaluation or a Ray wait of minutes: found by trying 135
bad inputs as a user would, 2026-12-07). Checks in process where the wiring is shared; one command each where it
is not."""

import json
import shutil
import socket
from pathlib import Path

import pytest
from conftest import assert_cli_error

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import check_writable_location
from adademo_lerobot.evaluation.policy import check_checkpoint_folder
from adademo_lerobot.executors import ExecutionArgs, check_torch_device, unreachable_head
from adademo_lerobot.loop.run_state import read_run_state

QUICKSTART = Path(__file__).resolve().parents[1] / "recipes" / "quickstart.yaml"


def damaged(ckpt, folder, damage: str):
    """A copy of the checkpoint `ckpt` with one kind of damage."""
    shutil.copytree(ckpt, folder)
    config = folder / "config.json"
    if damage == "broken_json":
        config.write_text(config.read_text()[:40])
    elif damage == "no_type":
        config.write_text(
            json.dumps({k: v for k, v in json.loads(config.read_text()).items() if k != "type"})
        )
    elif damage == "truncated_weights":
        weights = folder / "model.safetensors"
        weights.write_bytes(weights.read_bytes()[:500])
    return folder


@pytest.mark.parametrize(
    "damage, message",
    [
        ("broken_json", "config.json is not valid JSON"),
        ("no_type", "config.json names no policy type"),
        ("truncated_weights", "model.safetensors cannot be read"),
    ],
)
def test_a_damaged_checkpoint_is_refused_before_it_is_loaded(ckpt, tmp_path, damage, message):
    folder = damaged(ckpt, tmp_path / damage, damage)
    with pytest.raises(AdaDemoError, match=message):
        check_checkpoint_folder(folder)
    assert check_checkpoint_folder(ckpt) == ckpt


def test_training_from_truncated_weights_is_one_error_line(ckpt, reach_push_dataset, tmp_path):
    folder = damaged(ckpt, tmp_path / "ckpt", "truncated_weights")
    out = tmp_path / "out"
    assert_cli_error(
        "adademo-train", "--dataset.repo_id=local/demo", f"--dataset.root={reach_push_dataset}",
        f"--policy.path={folder}", "--steps=2", f"--output_dir={out}",
        match="model.safetensors cannot be read",
    )  # fmt: skip
    assert not out.exists()


@pytest.mark.parametrize(
    "content, message",
    [
        ("suite: [metaworld\ntrain: 3\n", "is not valid YAML: expected ',' or ']', but got ':' at line 2"),
        ("- suite\n- train\n", "is a YAML list, not a mapping of settings"),
        ("", "is empty, not a mapping of settings"),
    ],
)
def test_a_recipe_that_is_not_a_mapping_of_settings_is_one_error_line(tmp_path, content, message):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(content)
    run_dir = tmp_path / "run"
    assert_cli_error("adademo-run", f"--config_path={recipe}", f"--run_dir={run_dir}", match=message)
    assert not run_dir.exists()


def test_a_run_state_edited_by_hand_is_refused_as_not_a_run(tmp_path):
    assert read_run_state(tmp_path) is None  # no run here yet
    (tmp_path / "run_state.json").write_text("{oops")
    with pytest.raises(AdaDemoError, match="run_state.json is not valid JSON"):
        read_run_state(tmp_path)
    (tmp_path / "run_state.json").write_text(json.dumps({"settings": {}}))
    with pytest.raises(AdaDemoError, match="holds no run settings and stages"):
        read_run_state(tmp_path)
    (tmp_path / "run_state.json").write_text(json.dumps({"settings": {}, "done": {}}))
    assert read_run_state(tmp_path) == {"settings": {}, "done": {}}


def test_a_file_where_a_folder_goes_is_refused_before_the_evaluation_runs(ckpt, tmp_path):
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    with pytest.raises(AdaDemoError, match="is a file, not a folder"):
        check_writable_location(taken / "sub", "--output_dir")
    check_writable_location(tmp_path / "new" / "sub", "--output_dir")  # a writable ancestor is enough
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]  # the check left nothing
    assert_cli_error(
        "adademo-eval", f"--policy.path={ckpt}", "--suite.type=metaworld", "--suite.tasks=reach-v3,push-v3",
        "--episodes_per_task=1", f"--output_dir={taken}",
        match=f"cannot write --output_dir {taken}: {taken} is a file, not a folder",
    )  # fmt: skip
    assert taken.read_text() == "mine"


def test_a_device_torch_does_not_have_is_refused():
    check_torch_device("cpu")
    with pytest.raises(AdaDemoError, match="is not a torch device"):
        check_torch_device("tpu")
    import torch

    if not torch.cuda.is_available():
        with pytest.raises(AdaDemoError, match="torch finds no cuda device"):
            ExecutionArgs(device="cuda").validate_execution()
    # On Ray the workers use the device, and they may have one the driver lacks: not checked here.
    ExecutionArgs(device="cuda:7", executor="ray").validate_execution()


def test_a_ray_head_nothing_listens_at_is_refused_at_once(tmp_path):
    with socket.socket() as probe:  # a port nothing listens on once closed
        probe.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{probe.getsockname()[1]}"
    assert unreachable_head(address) == "Connection refused"
    assert unreachable_head("auto") is None and unreachable_head(None) is None
    assert unreachable_head("no-port-here") == "'no-port-here' is not HOST:PORT"
    with socket.create_server(("127.0.0.1", 0)) as server:
        assert unreachable_head(f"ray://127.0.0.1:{server.getsockname()[1]}") is None
    root = tmp_path / "ds"
    assert_cli_error(
        "adademo-collect", "--suite.tasks=reach-v3", "--episodes_per_task=1", "--dataset.repo_id=local/x",
        f"--dataset.root={root}", "--executor=ray", f"--ray.address={address}",
        match=f"cannot reach the Ray cluster at --ray.address={address}: Connection refused",
    )  # fmt: skip
    assert not root.exists()


@pytest.mark.parametrize(
    "command, args, message",
    [
        ("adademo-collect", ["--commit_every=0"], "--commit_every must be >= 1, got 0"),
        ("adademo-expand", ["--commit_every=0"], "--commit_every must be >= 1, got 0"),
        (
            "adademo-run",
            ["--eval.episodes_per_task=0"],
            "--eval.episodes_per_task and --eval.batch_size must be",
        ),
    ],
)
def test_counts_below_one_are_refused_by_every_command_that_takes_them(command, args, message, tmp_path):
    common = {
        "adademo-collect": [
            "--suite.tasks=reach-v3",
            "--dataset.repo_id=local/x",
            f"--dataset.root={tmp_path}/ds",
        ],
        "adademo-expand": [
            "--dataset.repo_id=local/x",
            f"--dataset.root={tmp_path}/ds",
            f"--policy.path={tmp_path}/ckpt",
        ],
        "adademo-run": [f"--config_path={QUICKSTART}", f"--run_dir={tmp_path}/run"],
    }[command]
    assert_cli_error(command, *common, *args, match=message)
    assert sorted(tmp_path.iterdir()) == []


def test_a_dataset_report_has_no_runs_to_compare(reach_push_dataset, tmp_path):
    assert_cli_error(
        "adademo-report", f"--dataset_root={reach_push_dataset}", f"--compare_to={tmp_path}/uniform",
        match="a --dataset_root report has no run to compare",
    )  # fmt: skip
