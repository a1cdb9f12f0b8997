"""What LeRobot users rely on across the move to LeRobot 0.6: datasets and checkpoints made before it still work,
and datasets edited with LeRobot's own tools keep working with every adademo command."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import BIN, TINY_ACT, run_cli

from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata

FIXTURES = Path(__file__).parent / "fixtures" / "lerobot044"


def stock_dataset(repo_id: str, root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, root=root, video_backend="pyav")


def expand_uniform(root: Path, repo_id: str = "local/x", n: int = 1) -> None:
    run_cli(
        "adademo-expand",
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={root}",
        "--strategy.type=uniform",
        f"--strategy.demos_per_task={n}",
    )


def test_a_dataset_made_with_lerobot_044_opens_trains_and_expands(tmp_path):
    root = tmp_path / "old"
    shutil.copytree(FIXTURES / "dataset", root)
    before = read_episode_metadata(root)
    assert len(before) == 6 and sorted(set(before["adademo/round"])) == [0, 1]
    assert stock_dataset("local/made_with_lerobot044", root).num_episodes == 6
    expand_uniform(root, n=2)  # round 2: new episodes appended to the old files' dataset
    after = read_episode_metadata(root)
    assert len(after) == 10 and (after[after["adademo/round"] == 2]["adademo/source"] == "uniform").all()
    assert [r["round"] for r in read_ledger(root)] == [1, 1, 2, 2]
    assert stock_dataset("local/made_with_lerobot044", root).num_episodes == 10
    out = tmp_path / "train"
    run_cli(
        "adademo-train",
        "--dataset.repo_id=local/made_with_lerobot044",
        f"--dataset.root={root}",
        *TINY_ACT,
        "--steps=2",
        f"--output_dir={out}",
    )
    assert (out / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").exists()


@pytest.mark.slow
def test_a_checkpoint_made_with_lerobot_044_evaluates_and_fine_tunes(tmp_path):
    ckpt, root = FIXTURES / "act_checkpoint", tmp_path / "old"
    shutil.copytree(FIXTURES / "dataset", root)
    run_cli(
        "adademo-eval",
        f"--policy.path={ckpt}",
        f"--dataset.root={root}",
        "--episodes_per_task=2",
        f"--output_dir={tmp_path / 'eval'}",
    )
    summary = json.loads((tmp_path / "eval" / "eval_summary.json").read_text())
    assert [row["episodes"] for row in summary["per_task"]] == [2, 2, 4]
    run_cli(
        "adademo-train",
        "--dataset.repo_id=local/made_with_lerobot044",
        f"--dataset.root={root}",
        f"--policy.path={ckpt}",
        "--steps=2",
        "--batch_size=8",
        f"--output_dir={tmp_path / 'ft'}",
    )


def test_expand_accepts_a_stock_lerobot_train_checkpoint(reach_push_dataset, stock_act_checkpoint, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(reach_push_dataset, root)
    run_cli(
        "adademo-expand",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        f"--policy.path={stock_act_checkpoint}",
        "--strategy.type=adademo",
        "--strategy.target_successes=1",
        "--strategy.max_demos_per_task=1",
    )
    assert {r["policy_path"] for r in read_ledger(root)} == {str(stock_act_checkpoint)}


def edit_dataset(*args: str) -> None:
    proc = subprocess.run(
        [str(BIN / "lerobot-edit-dataset"), *args], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]


def check_expands_and_opens(root: Path, repo_id: str, tasks: list[str]) -> None:
    """Every adademo command reads the edited dataset; a round appends to it; stock LeRobot still opens it."""
    before = read_episode_metadata(root)
    expand_uniform(root, repo_id)
    after = read_episode_metadata(root)
    new = after[after["adademo/round"] == after["adademo/round"].max()]
    assert len(after) == len(before) + len(tasks) and sorted(new["task"]) == sorted(tasks)
    assert (new["adademo/source"] == "uniform").all() and all(
        len(s) > 0 for s in new["adademo/initial_state"]
    )
    assert stock_dataset(repo_id, root).num_episodes == len(after)
    suite = json.loads((root / "meta" / "adademo" / "suite.json").read_text())
    assert suite["type"] == "metaworld" and suite["tasks"] == ",".join(tasks)


@pytest.fixture
def two_datasets(reach_push_dataset, tmp_path):
    """The session dataset and a second one of the same suite, with one adademo round each."""
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(reach_push_dataset, a)
    run_cli(
        "adademo-collect",
        "--suite.tasks=reach-v3,push-v3",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/b",
        f"--dataset.root={b}",
        "--seed=7",
    )
    return a, b


@pytest.mark.slow
def test_lerobot_merge_keeps_the_rounds_and_the_result_expands(two_datasets, tmp_path):
    a, b = two_datasets
    merged = tmp_path / "merged"
    edit_dataset(
        "--new_repo_id=local/merged",
        f"--new_root={merged}",
        "--operation.type=merge",
        "--operation.repo_ids=['local/demo', 'local/b']",
        f"--operation.roots=['{a}', '{b}']",
    )
    eps = read_episode_metadata(merged)
    assert (
        len(eps) == 6 + 2 and (eps["adademo/source"] == "initial").all()
    )  # LeRobot's merge keeps our columns
    assert not (merged / "meta" / "adademo" / "suite.json").exists()  # ... but copies no extra file
    check_expands_and_opens(merged, "local/merged", ["reach-v3", "push-v3"])
    assert (read_episode_metadata(merged)["adademo/round"].max()) == 1


@pytest.mark.slow
def test_lerobot_delete_episodes_drops_our_columns_and_the_result_still_expands(reach_push_dataset, tmp_path):
    source, out = tmp_path / "src", tmp_path / "deleted"
    shutil.copytree(reach_push_dataset, source)
    edit_dataset(
        "--repo_id=local/demo",
        f"--root={source}",
        "--new_repo_id=local/deleted",
        f"--new_root={out}",
        "--operation.type=delete_episodes",
        "--operation.episode_indices=[1]",
    )
    eps = read_episode_metadata(out)
    assert len(eps) == 5 and (eps["adademo/source"] == "imported").all()  # rebuilt: round 0, no initial state
    check_expands_and_opens(out, "local/deleted", ["reach-v3", "push-v3"])
    eps = read_episode_metadata(out)
    assert list(eps["adademo/round"]) == [0] * 5 + [1, 1]  # the old episodes were given the columns too


@pytest.mark.slow
def test_lerobot_split_results_each_expand(reach_push_dataset, tmp_path):
    source, base = tmp_path / "src", tmp_path / "split"
    shutil.copytree(reach_push_dataset, source)
    # Episodes 0-2 are reach-v3 and 3-5 push-v3: each part keeps both tasks (the one-hot order comes from frames).
    edit_dataset(
        "--repo_id=local/demo",
        f"--root={source}",
        f"--new_root={base}",
        "--operation.type=split",
        "--operation.splits={'train': [0, 1, 3, 4], 'val': [2, 5]}",
    )
    for part, n in (("train", 4), ("val", 2)):
        assert len(read_episode_metadata(base / part)) == n
        check_expands_and_opens(base / part, f"local/demo_{part}", ["reach-v3", "push-v3"])


def test_lerobot_aggregate_keeps_the_rounds_and_the_result_expands(two_datasets, tmp_path):
    from lerobot.datasets.aggregate import aggregate_datasets

    a, b = two_datasets
    out = tmp_path / "aggregated"
    aggregate_datasets(["local/demo", "local/b"], "local/aggregated", roots=[a, b], aggr_root=out)
    eps = read_episode_metadata(out)
    assert len(eps) == 8 and list(eps["adademo/seed"][:6]) == list(read_episode_metadata(a)["adademo/seed"])
    np.testing.assert_array_equal(
        eps["adademo/initial_state"].iloc[6], read_episode_metadata(b)["adademo/initial_state"].iloc[0]
    )
    check_expands_and_opens(out, "local/aggregated", ["reach-v3", "push-v3"])


def test_the_training_api_detected_is_the_installed_lerobots_and_a_checkpoint_resumes_exactly(tmp_path):
    """lerobot_training picks LeRobot 0.6.1's save/resume or LeRobot main's (PR #4010) by what is installed; a
    checkpoint written through it (as adademo-train writes it) resumes to the same step, RNG, optimizer and scheduler
    state, each loaded where adademo-train loads it (before or after `accelerator.prepare`)."""
    import inspect
    from importlib.metadata import version

    import torch
    from accelerate import Accelerator
    from lerobot.common import train_utils
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy

    from adademo_lerobot.loop import lerobot_training
    from adademo_lerobot.loop.train import (
        AdaDemoTrainConfig,
        TrainDatasetConfig,
        find_last_checkpoint,
        save_whole_checkpoint,
    )

    # Told apart by LeRobot's own signatures, not by the detection's test.
    new_api = "accelerator" in inspect.signature(train_utils.save_checkpoint).parameters
    assert lerobot_training.two_phase_resume() is new_api
    assert hasattr(train_utils, "load_training_state") is not new_api
    if version("lerobot") == "0.6.1":  # requirements.lock's
        assert not new_api

    def setup(resume: bool):
        policy_cfg = ACTConfig(
            dim_model=32, dim_feedforward=64, n_heads=2, n_encoder_layers=1, n_decoder_layers=1,
            n_vae_encoder_layers=1, chunk_size=10, n_action_steps=5, device="cpu",
            input_features={"observation.environment_state": PolicyFeature(FeatureType.ENV, (6,))},
            output_features={"action": PolicyFeature(FeatureType.ACTION, (4,))},
        )  # fmt: skip
        cfg = AdaDemoTrainConfig(
            dataset=TrainDatasetConfig(repo_id="local/demo", root=str(tmp_path / "dataset")),
            policy=policy_cfg,
            output_dir=tmp_path / "run",
            steps=10,
            batch_size=8,
            resume=resume,
        )
        cfg.optimizer = policy_cfg.get_optimizer_preset()
        cfg.scheduler = CosineDecayWithWarmupSchedulerConfig(
            num_warmup_steps=2, num_decay_steps=10, peak_lr=1e-3, decay_lr=1e-5
        )
        policy = ACTPolicy(policy_cfg)
        return cfg, policy, *make_optimizer_and_scheduler(cfg, policy)

    torch.manual_seed(0)
    cfg, policy, optimizer, scheduler = setup(resume=False)
    for _ in range(3):
        for p in policy.parameters():
            p.grad = torch.randn_like(p)
        optimizer.step()
        scheduler.step()
    rng = torch.get_rng_state()
    save_whole_checkpoint(cfg, 3, policy, optimizer, scheduler, None, None, {}, 1)
    last = find_last_checkpoint(cfg.output_dir)
    assert last == cfg.output_dir / "checkpoints" / "000003"
    assert {p.name for p in (last / "training_state").iterdir()} == {
        "optimizer_param_groups.json",
        "optimizer_state.safetensors",
        "rng_state.safetensors",
        "scheduler_state.json",
        "training_step.json",
    }
    step_file = json.loads((last / "training_state" / "training_step.json").read_text())
    if new_api:
        assert step_file["step"] == 3 and step_file["dp_world_size"] == 1 and step_file["batch_size"] == 8
    else:
        # As adademo-train has always written it on LeRobot 0.6.1.
        assert step_file == {"step": 3, "num_processes": 1, "batch_size": 8}

    # Another RNG state, a fresh optimizer and scheduler: all must come from the checkpoint.
    torch.manual_seed(1)
    cfg, policy, optimizer2, scheduler2 = setup(resume=True)
    cfg.checkpoint_path = last
    assert lerobot_training.resume_before_prepare(cfg, optimizer2, scheduler2) == 3
    assert torch.equal(torch.get_rng_state(), rng)
    accelerator = Accelerator(cpu=True, step_scheduler_with_optimizer=False)
    policy, optimizer2, scheduler2 = accelerator.prepare(policy, optimizer2, scheduler2)
    lerobot_training.resume_after_prepare(cfg, accelerator, policy, optimizer2, scheduler2)
    saved, resumed = optimizer.state_dict(), optimizer2.state_dict()
    assert saved["param_groups"] == resumed["param_groups"]
    assert saved["state"].keys() == resumed["state"].keys()
    for key, state in saved["state"].items():
        for name, value in state.items():
            assert torch.equal(value, resumed["state"][key][name]), (key, name)
    assert scheduler2.state_dict() == scheduler.state_dict()
    assert optimizer2.param_groups[0]["lr"] == optimizer.param_groups[0]["lr"]


def test_lerobot_train_flags_newer_than_0_6_1_are_refused_where_installed():
    """LeRobot main's --parallelism.*, --accelerator.*, --checkpoint_format, --ema.*, --dataset.exclude_episodes
    would be ignored by adademo-train's loop: they are in NOT_IMPLEMENTED exactly when the installed LeRobot has
    them."""
    import dataclasses

    from lerobot.configs.train import TrainPipelineConfig

    from adademo_lerobot.loop.lerobot_training import NEWER_UNIMPLEMENTED_FLAGS
    from adademo_lerobot.loop.train import NOT_IMPLEMENTED

    assert set(NEWER_UNIMPLEMENTED_FLAGS) <= set(NOT_IMPLEMENTED)
    installed = {f.name for f in dataclasses.fields(TrainPipelineConfig)}
    assert ("parallelism" in NEWER_UNIMPLEMENTED_FLAGS) is ("parallelism" in installed)
