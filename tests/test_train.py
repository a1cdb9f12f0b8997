"""adademo-train on real datasets: ACT and Diffusion, reload, fine-tune from stock lerobot-train, resume, errors."""

import copy
import json
import os
import re
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest
import torch
from conftest import BIN, TINY_ACT, TINY_ACT_POLICY, assert_cli_error, run_cli

TINY_DIFFUSION = [
    "--policy.type=diffusion",
    "--policy.down_dims=[32,64]",
    "--policy.diffusion_step_embed_dim=32",
    "--policy.horizon=16",
    "--policy.n_action_steps=8",
    "--policy.num_inference_steps=4",
    "--policy.device=cpu",
    "--batch_size=8",
]


def data_args(root):
    return ["--dataset.repo_id=local/demo", f"--dataset.root={root}"]


def load(ckpt):
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(ckpt)
    cfg.pretrained_path = ckpt
    policy = get_policy_class(cfg.type).from_pretrained(ckpt, config=cfg)
    policy.eval()
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(ckpt))
    return policy, pre, post


def first_action(ckpt, dataset_root, seed=0):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    item = LeRobotDataset("local/demo", root=dataset_root)[0]
    obs = {k: v.unsqueeze(0) for k, v in item.items() if k.startswith("observation.")}
    obs["task"] = [item["task"]]
    policy, pre, post = load(ckpt)
    torch.manual_seed(seed)
    with torch.inference_mode():
        return post(policy.select_action(pre(obs))).numpy()


def test_act_checkpoint_is_standard_and_reloads_to_identical_actions(act_run, reach_push_dataset):
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    assert (act_run / "checkpoints" / "000004" / "training_state" / "training_step.json").exists()
    assert {"config.json", "model.safetensors", "policy_preprocessor.json", "train_config.json"} <= {
        p.name for p in ckpt.iterdir()
    }
    config = json.loads((ckpt / "config.json").read_text())
    assert config["type"] == "act" and config["normalization_mapping"]["ENV"] == "MEAN_STD"
    # LeRobot's own train config reads it back (ours are beside it, in adademo_train.json).
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.policies.act.configuration_act import ACTConfig  # noqa: F401  (registers `act`, as lerobot-train)

    train_cfg = TrainPipelineConfig.from_pretrained(ckpt)
    assert type(train_cfg) is TrainPipelineConfig and train_cfg.steps == 4 and train_cfg.policy.type == "act"
    assert "sampler" not in json.loads((ckpt / "train_config.json").read_text())
    a1, a2 = first_action(ckpt, reach_push_dataset), first_action(ckpt, reach_push_dataset)
    np.testing.assert_array_equal(a1, a2)
    assert a1.shape == (1, 4)
    # The weights are the trained ones, not a fresh init: an earlier checkpoint acts differently.
    a_step2 = first_action(act_run / "checkpoints" / "000002" / "pretrained_model", reach_push_dataset)
    assert not np.array_equal(a1, a_step2)
    info = json.loads((ckpt / "adademo_train.json").read_text())
    assert info["episodes_per_task"] == {"reach-v3": 3, "push-v3": 3}
    assert info["sampler"] == "trajectory" and info["lr_schedule"] in ("preset", "cosine")


def test_diffusion_learns_and_reloads(reach_push_dataset, tmp_path):
    out = tmp_path / "diffusion"
    proc = run_cli(
        "adademo-train",
        *data_args(reach_push_dataset),
        *TINY_DIFFUSION,
        "--policy.optimizer_lr=0.001",
        "--batch_size=16",
        "--steps=120",
        "--log_freq=30",
        f"--output_dir={out}",
        "--sampler=task",
        # One thread: with two, any other busy process on a 2-core machine made this 12 s test take 275 s.
        "--torch_threads=1",
    )
    losses = [float(x) for x in re.findall(r"loss:([0-9.]+)", proc.stdout)]
    assert len(losses) == 4 and losses[-1] < 0.95 * losses[0], losses  # the denoising loss fell: it learned
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((ckpt / "config.json").read_text())["type"] == "diffusion"
    np.testing.assert_array_equal(
        first_action(ckpt, reach_push_dataset, 1), first_action(ckpt, reach_push_dataset, 1)
    )


def test_fine_tune_from_a_stock_lerobot_train_checkpoint(reach_push_dataset, stock_act_checkpoint, tmp_path):
    out = tmp_path / "finetuned"
    run_cli(
        "adademo-train",
        *data_args(reach_push_dataset),
        f"--policy.path={stock_act_checkpoint}",
        "--steps=2",
        "--batch_size=8",
        f"--output_dir={out}",
    )
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((ckpt / "config.json").read_text())["dim_model"] == 32
    assert first_action(ckpt, reach_push_dataset).shape == (1, 4)
    # Its inputs stay as the stock checkpoint learned them: our ENV normalization is for training from scratch.
    stock = json.loads((stock_act_checkpoint / "config.json").read_text())["normalization_mapping"]
    assert "ENV" not in stock
    assert json.loads((ckpt / "config.json").read_text())["normalization_mapping"] == stock


def test_a_resumed_training_ends_with_the_weights_of_an_uninterrupted_one(reach_push_dataset, tmp_path):
    """Stopped at a checkpoint and resumed, training continues the same random draws (dropout, the VAE's noise) as
    an uninterrupted run: the final weights are equal bit for bit."""
    from safetensors.torch import load_file

    common = [*data_args(reach_push_dataset), *TINY_ACT, "--save_freq=3", "--torch_threads=1"]
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    run_cli("adademo-train", *common, "--steps=6", f"--output_dir={whole}")
    run_cli("adademo-train", *common, "--steps=3", f"--output_dir={stopped}")  # as if stopped after step 3
    run_cli("adademo-train", *common, "--steps=6", f"--output_dir={stopped}", "--resume=true")

    def weights(out):
        return load_file(out / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")

    a, b = weights(whole), weights(stopped)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    first = load_file(whole / "checkpoints" / "000003" / "pretrained_model" / "model.safetensors")
    assert not all(torch.equal(a[k], first[k]) for k in a)  # steps 4-6 changed the weights
    # Killed after the final checkpoint was renamed into place, before `last` moved to it: the rerun finds the
    # training finished at step 6 and points `last` there (it returned step 3's policy as the result).
    last = whole / "checkpoints" / "last"
    last.unlink()
    last.symlink_to("000003")
    proc = run_cli("adademo-train", *common, "--steps=6", f"--output_dir={whole}", "--resume=true")
    assert (
        "training already finished at step 6" in proc.stdout + proc.stderr and last.resolve().name == "000006"
    )
    # Resumed with another batch size, the sampler would skip the wrong number of draws: refused.
    args = [*data_args(reach_push_dataset), *TINY_ACT_POLICY, "--batch_size=4", "--save_freq=3"]
    assert_cli_error(
        "adademo-train", *args, "--steps=9", f"--output_dir={whole}", "--resume=true",
        match="trained with --batch_size=8: resume with the same",
    )  # fmt: skip


def test_ctrl_c_saves_the_step_it_stopped_at_and_the_resumed_training_equals_an_uninterrupted_one(
    reach_push_dataset, tmp_path
):
    """A Ctrl-C between checkpoints finishes the step, saves it and exits 130; resumed from there, the training
    ends with an uninterrupted one's weights and checkpoints (the interrupt's checkpoint is removed at the next).
    Batches come from a loader worker, and the Ctrl-C goes to the whole process group, as a terminal's does (and
    `kill -TERM -PGID`): the worker, outside that group, gets none of it."""
    import psutil  # accelerate's dependency
    from safetensors.torch import load_file

    from adademo_lerobot.loop.train import find_last_checkpoint, saved_on_interrupt

    steps = ["--steps=60", "--save_freq=20", "--torch_threads=1", "--in_memory=false", "--num_workers=1"]
    common = [*data_args(reach_push_dataset), *TINY_ACT, *steps]
    stopped, whole = tmp_path / "stopped", tmp_path / "whole"
    proc = subprocess.Popen(
        [str(BIN / "adademo-train"), *common, f"--output_dir={stopped}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # Ctrl-C as in a terminal, even when the suite itself runs in the background (which ignores SIGINT).
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        start_new_session=True,
    )
    deadline = time.time() + 300
    while find_last_checkpoint(stopped) is None:  # step 20 saved: stop between it and step 40
        assert time.time() < deadline and proc.poll() is None, "training did not reach step 20"
        time.sleep(0.02)
    # The loader's workers are outside the group the signal goes to: only the training stops them (when the
    # signal comes while it waits for a batch, a worker killed by it would fail the training before it saves).
    workers = [p for p in psutil.Process(proc.pid).children() if p.name() == "pt_data_worker"]  # torch's name
    assert workers and all(os.getpgid(w.pid) != proc.pid for w in workers), workers
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: to the command and its process group
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "DataLoader worker" not in err, err[-2000:]
    resume = "interrupted: rerun the same command with --resume=true to continue from the last checkpoint"
    assert err.strip().splitlines()[-1] == resume
    step = int(re.search(r"stopped at step (\d+) and saved it", out + err).group(1))
    assert 20 <= step < 60, step  # the signal came after step 20's checkpoint, before the end
    held = find_last_checkpoint(stopped)
    assert int(held.name) == step and (step % 20 == 0) != saved_on_interrupt(held)
    run_cli("adademo-train", *common, f"--output_dir={stopped}", "--resume=true")
    run_cli("adademo-train", *common, f"--output_dir={whole}")

    def weights(out):
        return load_file(out / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")

    a, b = weights(whole), weights(stopped)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    names = [sorted(p.name for p in (out / "checkpoints").iterdir()) for out in (whole, stopped)]
    assert names[0] == names[1] == ["000020", "000040", "000060", "last"]


@pytest.mark.slow
def test_resume_after_kill_loses_at_most_the_steps_since_the_last_checkpoint(reach_push_dataset, tmp_path):
    out = tmp_path / "killed"
    args = [*data_args(reach_push_dataset), *TINY_ACT, "--steps=400", "--save_freq=3", f"--output_dir={out}"]
    proc = subprocess.Popen(
        [str(BIN / "adademo-train"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.time() + 300
    while not (out / "checkpoints" / "000006" / "training_state" / "training_step.json").exists():
        assert time.time() < deadline and proc.poll() is None, "training did not reach step 6"
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    from adademo_lerobot.loop.train import find_last_checkpoint

    last = find_last_checkpoint(out)
    assert int(last.name) >= 6
    resumed = run_cli(
        "adademo-train",
        *data_args(reach_push_dataset),
        "--steps=400",
        f"--output_dir={out}",
        "--resume=true",
        "--batch_size=8",
        "--save_freq=3",
    )
    assert f"trained {400 - int(last.name)} steps" in resumed.stdout
    assert (
        json.loads((out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())[
            "step"
        ]
        == 400
    )


@pytest.mark.slow
def test_bad_input(reach_push_dataset, act_run, tmp_path):
    def fails(*args, match):
        return assert_cli_error("adademo-train", *args, match=match)

    common = [*data_args(reach_push_dataset), "--steps=1"]
    fails(*common, "--policy.type=pi0x", f"--output_dir={tmp_path / 'a'}", match="pi0x")
    fails(*common, *TINY_ACT, "--sampler=weighted", f"--output_dir={tmp_path / 'b'}", match="sampler")
    fails(
        *common, *TINY_ACT, "--min_task_weight=0.6", f"--output_dir={tmp_path / 'c'}", match="min_task_weight"
    )
    fails(*common, *TINY_ACT, f"--output_dir={act_run}", match="--resume=true")
    # lerobot-train flags this loop does not implement are refused, not ignored.
    fails(
        *common,
        *TINY_ACT,
        "--dataset.episodes=[0,1]",
        f"--output_dir={tmp_path / 'g'}",
        match="--dataset.episodes",
    )
    fails(
        *common,
        *TINY_ACT,
        "--eval.n_episodes=3",
        f"--output_dir={tmp_path / 'g'}",
        match="--eval is a lerobot",
    )
    fails(*common, *TINY_ACT, "--output_dir=/proc/version/out", match="output_dir")
    fails(
        *common,
        *TINY_ACT,
        "--sampler=tempered",
        "--sampler_alpha=-0.5",
        f"--output_dir={tmp_path / 'f'}",
        match="--sampler_alpha must be >= 0",
    )
    # A checkpoint trained on 2 tasks cannot be fine-tuned on a 3-task dataset (one-hot size differs).
    three = tmp_path / "three"
    run_cli(
        "adademo-collect",
        "--suite.tasks=reach-v3,push-v3,drawer-open-v3",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={three}",
    )
    fails(
        *data_args(three),
        "--steps=1",
        f"--policy.path={act_run / 'checkpoints/last/pretrained_model'}",
        f"--output_dir={tmp_path / 'e'}",
        match="observation.environment_state",
    )
    assert not any((tmp_path / d).exists() for d in "abcefg")


def test_trains_on_a_plain_lerobot_dataset(reach_push_dataset, tmp_path):
    """Training needs only LeRobot's format: no meta/adademo, no adademo columns, any robot type."""
    import pyarrow.parquet as pq

    plain = tmp_path / "plain"
    shutil.copytree(reach_push_dataset, plain)
    shutil.rmtree(plain / "meta" / "adademo")
    for f in (plain / "meta" / "episodes").rglob("*.parquet"):
        table = pq.read_table(f)
        pq.write_table(table.select([c for c in table.column_names if not c.startswith("adademo/")]), f)
    info = json.loads((plain / "meta" / "info.json").read_text())
    (plain / "meta" / "info.json").write_text(json.dumps({**info, "robot_type": "so101_follower"}))
    out = tmp_path / "out"
    run_cli(
        "adademo-train", *data_args(plain), *TINY_ACT, "--steps=2", f"--output_dir={out}", "--sampler=task"
    )
    saved = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "adademo_train.json").read_text())
    assert saved["episodes_per_task"] == {"reach-v3": 3, "push-v3": 3} and saved["suite"] is None


def test_in_memory_batches_are_lerobots_samples(reach_push_dataset):
    """The same keys, dtypes and values as LeRobot's per-sample loading collated, windows and padding included,
    for ACT's action chunk and Diffusion's observation history + action horizon."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from torch.utils.data import default_collate

    from adademo_lerobot.dataset.in_memory import InMemoryFrames

    fps = 80
    windows = {
        "act": {"action": [i / fps for i in range(10)]},
        "diffusion": {
            "observation.state": [-1 / fps, 0.0],
            "observation.environment_state": [-1 / fps, 0.0],
            "action": [(i - 1) / fps for i in range(16)],
        },
    }
    for delta_timestamps in windows.values():
        stock = LeRobotDataset("local/demo", root=reach_push_dataset, delta_timestamps=delta_timestamps)
        assert InMemoryFrames.supports(stock)
        frames = InMemoryFrames(stock)
        ends = [int(e["dataset_to_index"]) for e in stock.meta.episodes]
        indices = [0, 1, 5, ends[0] - 1, ends[0], ends[0] + 3, ends[-1] - 2, ends[-1] - 1, 7, 7]
        expected = default_collate([stock[i] for i in indices])
        batch = frames.__getitems__(indices)
        assert set(batch) == set(expected)
        assert batch["task"] == expected["task"]
        for key, value in expected.items():
            if key != "task":
                assert batch[key].dtype == value.dtype, key
                torch.testing.assert_close(batch[key], value, rtol=0, atol=0, msg=key)
        assert (
            batch["action_is_pad"][indices.index(ends[-1] - 1)].sum() > 0
        )  # a window past the episode's end


def test_the_weighted_sampler_is_sharded_across_processes():
    """Under `accelerate launch` each process keeps every n-th batch of the same draws: together the processes
    see exactly the batches of one sequence, none twice, n times as many per step as one process."""
    from accelerate.data_loader import prepare_data_loader
    from torch.utils.data import DataLoader

    from adademo_lerobot.samplers.weighted_sampler import WeightedFrameSampler

    weights = np.linspace(1.0, 3.0, 50)
    weights /= weights.sum()
    steps, batch = 6, 4
    everything = [
        b.tolist()
        for b in DataLoader(
            range(50), batch_size=batch, sampler=WeightedFrameSampler(weights, steps * batch * 2, seed=3)
        )
    ]
    shards = []
    for rank in range(2):
        loader = DataLoader(
            range(50), batch_size=batch, sampler=WeightedFrameSampler(weights, steps * batch * 2, seed=3)
        )
        shards.append(
            [
                b.tolist()
                for b in prepare_data_loader(loader, num_processes=2, process_index=rank, put_on_device=False)
            ]
        )
    assert [len(s) for s in shards] == [steps, steps]
    assert shards[0] == everything[0::2] and shards[1] == everything[1::2]


@pytest.mark.parametrize("policy", ["act", "diffusion"])
def test_updating_all_tensors_at_once_gives_the_same_weights(policy):
    """LeRobot's optimizer preset of ACT (AdamW) and Diffusion (Adam) on CPU, one tensor at a time (torch's
    default there) against all at once: the same weights, bit for bit, step after step."""
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    from adademo_lerobot.loop.train import update_all_tensors_at_once

    preset = {"act": ACTConfig, "diffusion": DiffusionConfig}[policy]().get_optimizer_preset()
    torch.manual_seed(0)
    layers = torch.nn.Sequential(
        torch.nn.TransformerEncoderLayer(32, 4, 64, dropout=0.0, batch_first=True), torch.nn.Linear(32, 6)
    )
    twin = copy.deepcopy(layers)
    start = [p.detach().clone() for p in layers.parameters()]
    one_at_a_time, at_once = preset.build(layers.parameters()), preset.build(twin.parameters())
    update_all_tensors_at_once(at_once)
    assert [g["foreach"] for g in one_at_a_time.param_groups] == [None]
    assert [g["foreach"] for g in at_once.param_groups] == [True]
    for _ in range(25):
        x = torch.randn(8, 10, 32)
        for model, optimizer in ((layers, one_at_a_time), (twin, at_once)):
            optimizer.zero_grad()
            model(x).square().mean().backward()
            optimizer.step()
    after = list(layers.parameters())
    assert all(torch.equal(a, b) for a, b in zip(after, twin.parameters(), strict=True))
    assert not any(torch.equal(a, s) for a, s in zip(after, start, strict=True))  # every tensor moved


def test_optimizer_state_saved_updating_all_at_once_resumes_in_stock_lerobot_and_back(tmp_path):
    """Saved through LeRobot's own optimizer-state functions, the state keeps torch's default, so stock
    lerobot-train (a new optimizer of the preset, as it builds one) loads it; loaded back into ours, it updates all
    at once again, with the moments restored."""
    from lerobot.optim.optimizers import load_optimizer_state, save_optimizer_state
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.utils.constants import OPTIMIZER_PARAM_GROUPS

    from adademo_lerobot.loop.train import update_all_tensors_at_once

    preset = ACTConfig().get_optimizer_preset()
    layer = torch.nn.Linear(4, 3)
    ours = preset.build(layer.parameters())
    update_all_tensors_at_once(ours)
    layer(torch.randn(5, 4)).sum().backward()
    ours.step()
    for folder in ("ours", "stock"):
        (tmp_path / folder).mkdir()  # as save_checkpoint makes it
    save_optimizer_state(ours, tmp_path / "ours")
    assert json.loads((tmp_path / "ours" / OPTIMIZER_PARAM_GROUPS).read_text())[0]["foreach"] is None
    stock = load_optimizer_state(preset.build(layer.parameters()), tmp_path / "ours")
    assert stock.param_groups[0]["foreach"] is None
    moments = ours.state[layer.weight]["exp_avg"]
    assert torch.equal(stock.state[stock.param_groups[0]["params"][0]]["exp_avg"], moments)
    save_optimizer_state(stock, tmp_path / "stock")
    again = preset.build(layer.parameters())
    update_all_tensors_at_once(again)
    again = load_optimizer_state(again, tmp_path / "stock")
    assert again.param_groups[0]["foreach"] is True
    assert torch.equal(again.state[layer.weight]["exp_avg"], moments)


@pytest.mark.slow
def test_trains_under_accelerate_launch_with_two_cpu_processes(reach_push_dataset, tmp_path):
    out = tmp_path / "ddp"
    proc = subprocess.run(
        [
            str(BIN / "accelerate"),
            "launch",
            "--cpu",
            "--num_processes=2",
            "--num_machines=1",
            "--mixed_precision=no",
            "--dynamo_backend=no",
            "-m",
            "adademo_lerobot.commands.train",
            *data_args(reach_push_dataset),
            *TINY_ACT,
            "--steps=6",
            "--save_freq=3",
            "--torch_threads=1",
            f"--output_dir={out}",
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    state = json.loads((out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 6 and first_action(
        out / "checkpoints" / "last" / "pretrained_model", reach_push_dataset
    ).shape == (1, 4)


@pytest.mark.slow
def test_trains_and_resumes_under_torchrun_with_two_cpu_processes(reach_push_dataset, tmp_path):
    """Two real processes (`accelerate launch --cpu` starts one), through LeRobot 0.6.1's save and resume or LeRobot
    main's (lerobot_training.py): the main process saves alone, and the checkpoint records both processes."""
    out = tmp_path / "torchrun"
    args = [
        *data_args(reach_push_dataset),
        *TINY_ACT,
        "--save_freq=3",
        "--torch_threads=1",
        f"--output_dir={out}",
    ]
    for steps, resume in ((3, "false"), (6, "true")):
        proc = subprocess.run(
            [str(BIN / "torchrun"), "--nproc-per-node=2", "-m", "adademo_lerobot.commands.train", *args]
            + [f"--steps={steps}", f"--resume={resume}"],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert proc.stdout.count("trained 3 steps") == 2  # one line per process
        state = json.loads(
            (out / "checkpoints" / "last" / "training_state" / "training_step.json").read_text()
        )
        assert state["step"] == steps and state.get("num_processes", state.get("dp_world_size")) == 2
