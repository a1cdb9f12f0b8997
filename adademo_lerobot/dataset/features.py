"""LeRobot feature specs of a suite's datasets (the one place they are built)."""

from __future__ import annotations

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import TaskSuite


def dataset_features(suite: TaskSuite) -> dict[str, dict]:
    """`observation.state`, `observation.environment_state`, `action` and, for `pixels_state`, the camera; in a
    robot view (`--suite.view=robot|robot_scene`), the adademo_sim robot's: no environment_state, named motors."""
    from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE  # imports torch: here

    cfg = suite.config
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (suite.state_dim,), "names": None},
        OBS_ENV_STATE: {"dtype": "float32", "shape": (suite.env_state_dim,), "names": None},
        ACTION: {"dtype": "float32", "shape": (suite.action_dim,), "names": None},
    }
    if getattr(cfg, "view", "env") != "env":
        from adademo_lerobot.suites.metaworld import ROBOT_ACTIONS, ROBOT_JOINTS

        scene = [f"scene.{i}" for i in range(suite.state_dim - len(ROBOT_JOINTS))]
        del features[OBS_ENV_STATE]
        features[OBS_STATE]["names"] = [*ROBOT_JOINTS, *scene]
        features[ACTION]["names"] = list(ROBOT_ACTIONS)
    if cfg.obs_type == "pixels_state":
        size = cfg.image_size
        features[f"{OBS_IMAGES}.{cfg.camera}"] = {
            "dtype": "video",
            "shape": (size, size, 3),
            "names": ["height", "width", "channels"],
        }
    return features


def check_features_match(found: dict[str, dict], suite: TaskSuite, what: str = "the dataset") -> None:
    """`found` (a dataset's info.json features) has the suite's observation and action features, same shapes,
    and no other observation: new demos from the suite's envs must fit beside its episodes."""
    expected = dataset_features(suite)
    problems = []
    for key, ft in expected.items():
        if key not in found:
            problems.append(f"{key} is missing")
        elif tuple(found[key]["shape"]) != tuple(ft["shape"]):
            problems.append(
                f"{key} has shape {tuple(found[key]['shape'])}, the suite's is {tuple(ft['shape'])}"
            )
    problems += [
        f"{k} is not a feature of the suite"
        for k in found
        if k.startswith("observation.") and k not in expected
    ]
    if problems:
        raise AdaDemoError(
            f"{what}'s features do not match the suite ({suite.name}: {','.join(suite.tasks)}): "
            + "; ".join(problems)
            + " (pass the suite the dataset was recorded with: --suite.type=... --suite.tasks=..."
            + (
                "; one recorded on a robot grows with adademo-record)"
                if "observation.environment_state" not in found
                else ")"
            )
        )
