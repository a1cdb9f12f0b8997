"""Our suites as a LeRobot env type: stock `lerobot-eval` evaluates our checkpoints on our tasks, found through
LeRobot's own third-party plugin discovery (the installed `lerobot_env_adademo` distribution)."""

import json
import subprocess

import numpy as np
import pandas as pd
import pytest
from conftest import BIN, requires_rendering


def test_stock_lerobot_eval_finds_our_env_plugin_and_needs_no_gl_with_recording(
    act_run, reach_push_dataset, tmp_path
):
    """No --env.discover_packages_path; --eval.recording=true turns LeRobot's videos off (so no OpenGL) and
    records the rollouts as a LeRobot dataset."""
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    out = tmp_path / "lerobot_eval"
    proc = subprocess.run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={ckpt}",
            "--env.type=adademo",
            f"--env.dataset_root={reach_push_dataset}",
            "--env.task=push-v3",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=false",
            "--eval.recording=true",
            "--policy.device=cpu",
            f"--output_dir={out}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env={**__import__("os").environ, "MUJOCO_GL": "disable"},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Imported third-party plugin: lerobot_env_adademo" in proc.stderr
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    assert not list(out.rglob("*.mp4"))
    recorded = list((out / "recordings").rglob("info.json"))
    assert recorded, "the rollouts were not recorded as a dataset"
    frames = pd.concat(pd.read_parquet(p) for p in (out / "recordings").rglob("data/*/*.parquet"))
    env_state = np.stack(frames["environment_state"].to_numpy())  # recorded under the env's own keys
    assert env_state.shape[1] == 41 and np.all(
        env_state[:, -1] == 1.0
    )  # push-v3 is the 2nd task of the one-hot


@pytest.mark.slow
@requires_rendering
def test_stock_lerobot_eval_renders_videos_of_state_envs(act_run, reach_push_dataset, tmp_path):
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    out = tmp_path / "lerobot_eval"
    proc = subprocess.run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={ckpt}",
            "--env.type=adademo",
            f"--env.dataset_root={reach_push_dataset}",
            "--env.task=reach-v3",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={out}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(list((out / "videos").rglob("*.mp4"))) == 1


def test_env_config_features_match_the_dataset(reach_push_dataset):
    from lerobot.envs.utils import env_to_policy_features

    from adademo_lerobot.lerobot_plugins.env import AdaDemoEnv

    cfg = AdaDemoEnv(dataset_root=str(reach_push_dataset), task="push-v3")
    features = env_to_policy_features(cfg)
    assert features["observation.environment_state"].shape == (41,)
    assert features["observation.state"].shape == (4,) and features["action"].shape == (4,)
    assert cfg.fps == 80


@requires_rendering
def test_state_env_renders_frames_for_videos():
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    env = make_suite(MetaWorldSuiteConfig(tasks="reach-v3")).make_env("reach-v3")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8 and frame.std() > 1
    env.close()
