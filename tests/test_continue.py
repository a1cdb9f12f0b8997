"""adademo-run from what a user already has: their dataset and checkpoint, local or on the hub (the hub double)."""

import json
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import BIN, assert_cli_error, file_digests, run_cli
from hub_double import HubDouble
from test_push import TOKEN, hub_env, run_python

from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata

CONTINUE = [
    "--config_path=recipes/continue_from_checkpoint.yaml",
    "--rounds=2",
    "--strategy.budget=[2]",
    "--strategy.max_demos_per_task=[2]",
    "--train.finetune_steps=4",
    "--train.save_freq=4",
    "--train.batch_size=8",
    "--eval.episodes_per_task=3",
]


@pytest.fixture(scope="module")
def checkpoint(act_run) -> Path:
    return act_run / "checkpoints" / "last" / "pretrained_model"


def started_from(run_dir: Path, round_index: int) -> Path | None:
    """The checkpoint round i's training started from, as its saved train_config.json says (None: scratch)."""
    trained = run_dir / "train" / f"round-{round_index}" / "checkpoints" / "last" / "pretrained_model"
    path = json.loads((trained / "train_config.json").read_text())["policy"]["pretrained_path"]
    return None if path is None else Path(path).resolve()


def round_checkpoint(run_dir: Path, round_index: int) -> Path:
    return (
        run_dir / "train" / f"round-{round_index}" / "checkpoints" / "last" / "pretrained_model"
    ).resolve()


def eval_policy(run_dir: Path, round_index: int) -> str:
    summary = json.loads((run_dir / "eval" / f"round-{round_index:03d}" / "eval_summary.json").read_text())
    return summary["policy_path"]


def test_continue_from_a_local_dataset_and_checkpoint_then_resume(reach_push_dataset, checkpoint, tmp_path):
    before = file_digests(reach_push_dataset)
    run_dir = tmp_path / "run"
    args = [
        *CONTINUE,
        f"--run_dir={run_dir}",
        "--dataset.repo_id=me/reach-push",
        f"--dataset.root={reach_push_dataset}",
        f"--policy.path={checkpoint}",
    ]
    proc = subprocess.Popen(
        [str(BIN / "adademo-run"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    state_path, deadline = run_dir / "run_state.json", time.time() + 600
    while not (state_path.exists() and "eval-0" in json.loads(state_path.read_text())["done"]):
        assert time.time() < deadline and proc.poll() is None, "the run ended before it could be killed"
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    rerun = run_cli("adademo-run", *args)
    assert "[done] start" in rerun.stdout and "[done] eval-0" in rerun.stdout
    assert "copied" not in rerun.stdout  # the copy is not made twice
    state = json.loads(state_path.read_text())
    assert list(state["done"]) == [
        "start",
        "eval-0",
        "expand-1",
        "train-1",
        "eval-1",
        "expand-2",
        "train-2",
        "eval-2",
    ]  # no collect, no train-0

    # Round 0 is the given checkpoint; round 1 fine-tunes from it, round 2 from round 1's (not the user's again).
    assert Path(eval_policy(run_dir, 0)) == checkpoint.resolve()
    assert started_from(run_dir, 1) == checkpoint.resolve()
    assert started_from(run_dir, 2) == round_checkpoint(run_dir, 1)
    assert Path(eval_policy(run_dir, 2)) == round_checkpoint(run_dir, 2)

    # The run expanded its own copy; the user's dataset is byte-for-byte what it was, and the run says so.
    copy = run_dir / "dataset"
    eps = read_episode_metadata(copy)
    assert (eps["adademo/round"] == 0).sum() == 6 and (eps["adademo/round"] == 1).sum() == 2
    assert (eps["adademo/round"] == 2).sum() == 2
    assert [r["round"] for r in read_ledger(copy)] == [1, 1, 2, 2]
    assert file_digests(reach_push_dataset) == before
    origin = json.loads((run_dir / "origin.json").read_text())
    assert origin["files"] == before
    assert origin["dataset"]["root"] == str(reach_push_dataset.resolve())
    assert origin["policy"]["path"] == str(checkpoint) and origin["policy"]["type"] == "act"
    report = (run_dir / "report" / "report.md").read_text()
    assert "Started from dataset me/reach-push" in report and "round 0: SR % (demos)" in report


@pytest.mark.slow
def test_continue_in_scratch_mode_trains_every_round_from_scratch(reach_push_dataset, checkpoint, tmp_path):
    """--train.mode=scratch: the user's checkpoint is round 0's policy and the architecture of later rounds, never
    their starting weights."""
    run_dir = tmp_path / "run"
    # Fine-tuning keeps the checkpoint's architecture: a recipe field that would change it is refused, not ignored.
    assert_cli_error(
        "adademo-run", *CONTINUE, f"--run_dir={run_dir}", f"--dataset.root={reach_push_dataset}",
        f"--policy.path={checkpoint}", "--train.policy.type=act", "--train.policy.dim_model=64",
        match="--train.policy.dim_model=64 differs from the checkpoint's dim_model=32",
    )  # fmt: skip
    assert not run_dir.exists()
    run_cli(
        "adademo-run",
        *CONTINUE,
        f"--run_dir={run_dir}",
        f"--dataset.root={reach_push_dataset}",
        f"--policy.path={checkpoint}",
        "--train.mode=scratch",
        "--train.steps=4",
    )
    assert started_from(run_dir, 1) is None and started_from(run_dir, 2) is None
    for i in (1, 2):
        config = json.loads((round_checkpoint(run_dir, i) / "config.json").read_text())
        assert config["dim_model"] == 32  # the checkpoint's architecture
        assert Path(eval_policy(run_dir, i)) == round_checkpoint(run_dir, i)


@pytest.mark.slow
def test_in_place_on_a_dataset_recorded_elsewhere_with_the_suite_flags(
    reach_push_dataset, checkpoint, tmp_path
):
    """No suite.json (as after LeRobot's own tools, or another recorder): the suite flags say how to build the
    envs; --dataset.copy=false expands the dataset itself, says so, and keeps the suite from then on."""
    mine = tmp_path / "mine"
    shutil.copytree(reach_push_dataset, mine)
    (mine / "meta" / "adademo" / "suite.json").unlink()
    run_dir = tmp_path / "run"
    proc = run_cli(
        "adademo-run",
        *CONTINUE,
        "--rounds=1",
        f"--run_dir={run_dir}",
        f"--dataset.root={mine}",
        "--dataset.copy=false",
        "--suite.type=metaworld",
        "--suite.tasks=reach-v3,push-v3",
        f"--policy.path={checkpoint}",
    )
    assert f"expanding {mine} in place" in proc.stdout
    assert not (run_dir / "dataset").exists()
    assert (read_episode_metadata(mine)["adademo/round"] == 1).sum() == 2
    assert json.loads((mine / "meta" / "adademo" / "suite.json").read_text())["tasks"] == "reach-v3,push-v3"
    assert "(demos)" in (run_dir / "report" / "report.md").read_text()


def test_a_copy_left_by_an_interrupted_start_is_replaced_whole(reach_push_dataset, tmp_path):
    """Killed after the copy was renamed into RUN_DIR/dataset but before the start stage was recorded: the rerun
    copies again over it (it failed with 'Directory not empty' on every rerun)."""
    from adademo_lerobot.loop.start import Start, prepare_dataset
    from adademo_lerobot.suites import SuiteConfig

    run_dataset = tmp_path / "run" / "dataset"
    (run_dataset / "meta").mkdir(parents=True)
    (run_dataset / "meta" / "stale.json").write_text("{}")  # what the interrupted copy left
    start = Start(reach_push_dataset, None, SuiteConfig.get_choice_class("metaworld")(), None, None, None)
    root, digests = prepare_dataset(start, True, run_dataset)
    assert root == run_dataset and not (run_dataset / "meta" / "stale.json").exists()
    assert file_digests(run_dataset) == digests == file_digests(reach_push_dataset)
    assert not (tmp_path / "run" / ".dataset.copying").exists()


def test_a_revision_that_would_be_ignored_is_refused(reach_push_dataset, checkpoint):
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.loop.start import StartDatasetArgs, StartPolicyArgs, check_start
    from adademo_lerobot.suites import SuiteConfig

    suite = SuiteConfig.get_choice_class("metaworld")()
    local = StartDatasetArgs(repo_id="local/demo", root=str(reach_push_dataset))
    for policy, says in (
        (StartPolicyArgs(path=str(checkpoint), revision="v1"), "a local folder has none: drop it"),
        (StartPolicyArgs(revision="v1"), "give --policy.path too"),
    ):
        with pytest.raises(AdaDemoError, match=f"--policy.revision=v1 .*{says}"):
            check_start(local, policy, suite, True)
    with pytest.raises(AdaDemoError, match="--dataset.revision=v1 .*local folder is used as it is"):
        check_start(
            StartDatasetArgs("local/demo", str(reach_push_dataset), "v1"), StartPolicyArgs(), suite, True
        )


@pytest.mark.slow
def test_bad_starting_points_get_one_error_and_nothing_is_written(reach_push_dataset, checkpoint, tmp_path):
    run_dir = tmp_path / "run"
    common = [*CONTINUE, f"--run_dir={run_dir}", f"--dataset.root={reach_push_dataset}"]
    assert_cli_error(
        "adademo-run", *common, f"--policy.path={checkpoint}", "--train.policy.type=diffusion",
        match="holds a act policy but the recipe trains diffusion",
    )  # fmt: skip
    assert_cli_error(
        "adademo-run", *common, f"--policy.path={checkpoint}", "--suite.tasks=reach-v3,window-open-v3",
        match="another suite configuration",
    )  # fmt: skip
    assert_cli_error("adademo-run", *common, f"--policy.path={tmp_path / 'nope'}", match="no checkpoint at")
    assert_cli_error(
        "adademo-run",
        *CONTINUE,
        f"--run_dir={run_dir}",
        f"--policy.path={checkpoint}",
        match="--dataset.repo_id",
    )
    assert_cli_error(
        "adademo-run",
        *CONTINUE,
        f"--run_dir={run_dir}",
        f"--dataset.root={tmp_path}",
        f"--policy.path={checkpoint}",
        match="no LeRobot dataset",
    )
    other = tmp_path / "other"  # a dataset of another suite, without suite.json: its features do not fit
    shutil.copytree(reach_push_dataset, other)
    (other / "meta" / "adademo" / "suite.json").unlink()
    before = file_digests(other)
    assert_cli_error(
        "adademo-run", *CONTINUE, f"--run_dir={run_dir}", f"--dataset.root={other}", "--dataset.copy=false",
        f"--policy.path={checkpoint}", "--suite.tasks=reach-v3", match="observation.environment_state has shape (41,), the suite's is (40,)",
    )  # fmt: skip
    assert file_digests(other) == before
    assert not run_dir.exists()


@pytest.fixture(scope="module")
def hub():
    with HubDouble(token=TOKEN, user="alice") as double:
        yield double


@pytest.mark.slow
def test_continue_from_a_hub_dataset_and_checkpoint(hub, reach_push_dataset, checkpoint, tmp_path):
    """A dataset and a checkpoint a test first pushes to the hub double, pinned by revision; then bad ids."""
    pushed = run_python(
        hub,
        tmp_path,
        f"""
        import json
        from huggingface_hub import HfApi
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        from adademo_lerobot.loop.push import _card_validation_on_endpoint

        with _card_validation_on_endpoint():  # the card's YAML check would go to huggingface.co
            LeRobotDataset("alice/reach-push", root={str(reach_push_dataset)!r}).push_to_hub()
        api = HfApi()
        api.create_repo("alice/tiny-act", exist_ok=True)
        api.upload_folder(repo_id="alice/tiny-act", folder_path={str(checkpoint)!r})
        print(json.dumps({{"dataset": api.dataset_info("alice/reach-push").sha,
                          "policy": api.model_info("alice/tiny-act").sha}}))
        """,
    )
    env = hub_env(hub, tmp_path, HF_LEROBOT_HOME=str(tmp_path / "lerobot_home"))

    def adademo_run(run_dir: Path, *args: str) -> subprocess.CompletedProcess:
        cmd = [str(BIN / "adademo-run"), *CONTINUE, f"--run_dir={run_dir}", *args]
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)

    run_dir = tmp_path / "run"
    proc = adademo_run(
        run_dir,
        "--rounds=2",
        "--dataset.repo_id=alice/reach-push",
        f"--dataset.revision={pushed['dataset']}",
        "--policy.path=alice/tiny-act",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    origin = json.loads((run_dir / "origin.json").read_text())
    assert origin["dataset"]["commit"] == pushed["dataset"] and origin["policy"]["commit"] == pushed["policy"]
    assert origin["files"] == file_digests(reach_push_dataset) | {
        k: v
        for k, v in origin["files"].items()
        if k in ("README.md", ".gitattributes")  # the card LeRobot's push added, the hub's default file
    }
    assert (tmp_path / "lerobot_home" / "hub").is_dir()  # LeRobot's own download location
    assert (read_episode_metadata(run_dir / "dataset")["adademo/round"] == 0).sum() == 6
    assert "alice--tiny-act" in eval_policy(run_dir, 0)
    # Round 1 fine-tunes from the downloaded checkpoint, round 2 from round 1's (the hub id is not read again).
    assert started_from(run_dir, 1) == Path(eval_policy(run_dir, 0)).resolve()
    assert started_from(run_dir, 2) == round_checkpoint(run_dir, 1)

    bad = tmp_path / "bad"
    for args, match in (
        (["--dataset.repo_id=alice/no-such-dataset"], "alice/no-such-dataset was not found on the hub"),
        (["--dataset.repo_id=alice/reach-push", "--dataset.revision=no-such-rev"], "has no revision 'no-such-rev'"),
        (["--dataset.repo_id=alice/reach-push", "--policy.path=alice/no-such-ckpt"], "alice/no-such-ckpt was not found"),
        (["--dataset.repo_id=alice/reach-push", "--dataset.copy=false"], "pass --dataset.root"),
    ):  # fmt: skip
        if not any(a.startswith("--policy.path") for a in args):
            args.append("--policy.path=alice/tiny-act")
        proc = adademo_run(bad, *args)
        assert proc.returncode == 2, proc.stderr[-2000:]
        last = proc.stderr.strip().splitlines()[-1]
        assert last.startswith("error:") and match in last, last
        assert not bad.exists()
