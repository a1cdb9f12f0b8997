"""LeRobot feature specs of a suite's datasets (the one place they are built)."""

from __future__ import annotations

from adademo_lerobot.suites.base import TaskSuite


def dataset_features(suite: TaskSuite) -> dict[str, dict]:
    """`observation.state`, `observation.environment_state`, `action` and, for `pixels_state`, the camera."""
    from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE  # imports torch: here

    cfg = suite.config
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (suite.state_dim,), "names": None},
        OBS_ENV_STATE: {"dtype": "float32", "shape": (suite.env_state_dim,), "names": None},
        ACTION: {"dtype": "float32", "shape": (suite.action_dim,), "names": None},
    }
    if cfg.obs_type == "pixels_state":
        size = cfg.image_size
        features[f"{OBS_IMAGES}.{cfg.camera}"] = {
            "dtype": "video",
            "shape": (size, size, 3),
            "names": ["height", "width", "channels"],
        }
    return features
