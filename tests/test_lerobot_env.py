"""Our suites as a LeRobot env type: stock `lerobot-eval` evaluates our checkpoints on our tasks."""

import ctypes.util
import json
import subprocess

import numpy as np
import pytest

from conftest import BIN


needs_osmesa = pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None, reason="needs libosmesa6 to render on CPU")


@needs_osmesa  # lerobot-eval 0.4.4 always renders videos of the first episodes
def test_stock_lerobot_eval_runs_our_checkpoint_on_our_suite(act_run, reach_push_dataset, tmp_path):
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    out = tmp_path / "lerobot_eval"
    proc = subprocess.run(
        [str(BIN / "lerobot-eval"), f"--policy.path={ckpt}", "--env.type=adademo",
         "--env.discover_packages_path=adademo_lerobot.envs", f"--env.dataset_root={reach_push_dataset}",
         "--env.task=push-v3", "--eval.n_episodes=2", "--eval.batch_size=2",
         "--policy.device=cpu", f"--output_dir={out}"],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    assert len(list((out / "videos").rglob("*.mp4"))) == 2


def test_env_config_features_match_the_dataset(reach_push_dataset):
    from lerobot.envs.utils import env_to_policy_features

    from adademo_lerobot.envs import AdaDemoEnv

    cfg = AdaDemoEnv(dataset_root=str(reach_push_dataset), task="push-v3")
    features = env_to_policy_features(cfg)
    assert features["observation.environment_state"].shape == (41,)
    assert features["observation.state"].shape == (4,) and features["action"].shape == (4,)
    assert cfg.fps == 80


@needs_osmesa
def test_state_env_renders_frames_for_videos(reach_push_dataset):
    from adademo_lerobot.suites import MetaWorldSuiteConfig, make_suite

    env = make_suite(MetaWorldSuiteConfig(tasks="reach-v3")).make_env("reach-v3")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8 and frame.std() > 1
    env.close()
