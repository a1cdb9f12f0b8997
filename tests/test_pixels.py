"""pixels_state: a rendered camera image joins the state observation (OSMesa on CPU machines)."""

import numpy as np
from conftest import requires_rendering, run_cli

pytestmark = requires_rendering


def test_pixels_state_dataset_has_camera_frames(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path / "pix"
    run_cli(
        "adademo-collect",
        "--suite.tasks=reach-v3",
        "--suite.obs_type=pixels_state",
        "--suite.image_size=64",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/pix",
        f"--dataset.root={root}",
    )
    ds = LeRobotDataset("local/pix", root=root, video_backend="pyav")
    assert ds.meta.features["observation.images.corner2"]["shape"] == (64, 64, 3)
    first, later = ds[0]["observation.images.corner2"], ds[20]["observation.images.corner2"]
    assert first.shape == (3, 64, 64)
    assert first.std() > 0.01  # a real picture, not a blank frame
    assert not np.allclose(first.numpy(), later.numpy())  # the arm moved
    assert ds[0]["observation.environment_state"].shape == (39 + 1,)
