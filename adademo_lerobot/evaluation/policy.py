"""Loading a LeRobot policy checkpoint and checking that it reads and writes a suite's features.

Every command that takes `--policy.path` goes through `load_checked_policy`, so a checkpoint of another
action size, another task list (one-hot size) or another observation set is refused with one line before
anything runs. LeRobot and torch are imported here, when a policy is actually loaded.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from adademo_lerobot.core.errors import AdaDemoError

POLICY_TYPES = ("act", "diffusion")
# How a trained policy turns its predictions into actions, not what it learned: a checkpoint read with other values
# is the same policy acting otherwise (ACT trained with n_action_steps 10, or 1 and temporal ensembling, ends with
# the same weights bit for bit: checked over 30 steps, 2026-12-06).
READOUT_FIELDS = ("n_action_steps", "temporal_ensemble_coeff")
READOUT_RECORD = "readout.json"  # in a readout folder: the checkpoint it reads and how


@dataclass
class LoadedPolicy:
    policy: Any  # a LeRobot PreTrainedPolicy (torch.nn.Module)
    preprocessor: Any
    postprocessor: Any
    config: Any  # its PreTrainedConfig
    path: Path


def check_checkpoint_folder(path: str | Path) -> Path:
    """A LeRobot checkpoint folder whose config names a policy type and whose weights file is whole as far as its
    header tells (read without loading a tensor), or one line saying what is wrong."""
    import json

    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not (path / "config.json").exists() or not (path / "model.safetensors").exists():
        raise AdaDemoError(
            f"no LeRobot checkpoint at {path} (expected config.json and model.safetensors; pass the "
            ".../checkpoints/last/pretrained_model folder)"
        )
    try:
        config = json.loads((path / "config.json").read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise AdaDemoError(
            f"{path / 'config.json'} is not valid JSON ({err}): a damaged checkpoint"
        ) from None
    if not isinstance(config, dict) or "type" not in config:
        raise AdaDemoError(f"{path / 'config.json'} names no policy type: not a LeRobot policy checkpoint")
    try:
        with safe_open(str(path / "model.safetensors"), framework="numpy") as weights:
            weights.keys()
    except (SafetensorError, OSError) as err:
        raise AdaDemoError(
            f"{path / 'model.safetensors'} cannot be read ({err}): the checkpoint's weights are damaged or were not "
            "fully written; pass another checkpoint"
        ) from None
    return path


def read_policy_config(path: Path):
    """The checkpoint's `PreTrainedConfig` (LeRobot's policy types are registered first)."""
    import lerobot.policies  # noqa: F401  (registers the policy config types by name)
    from lerobot.configs.policies import PreTrainedConfig

    return PreTrainedConfig.from_pretrained(path)


def load_policy(path: str | Path, device: str = "cpu") -> LoadedPolicy:
    """Any LeRobot ACT/Diffusion checkpoint folder (`.../pretrained_model`), ours or stock `lerobot-train`'s."""
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    path = check_checkpoint_folder(path)
    cfg = read_policy_config(path)
    if cfg.type not in POLICY_TYPES:
        raise AdaDemoError(f"{path} holds a {cfg.type!r} policy; adademo supports {', '.join(POLICY_TYPES)}")
    cfg.device = device
    cfg.pretrained_path = path
    policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    policy.eval()
    pre, post = make_pre_post_processors(
        cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": device}}
    )
    return LoadedPolicy(policy, pre, post, cfg, path)


# Where a checkpoint's features are checked against, unless a caller names another source.
SUITE_FEATURES = "the suite's observations and actions"


def check_policy_matches_features(
    policy_cfg, features: dict[str, dict], source: str = SUITE_FEATURES
) -> None:
    """A checkpoint must read and write exactly these dataset features (names and shapes); `source` names where
    they come from in the message."""
    from lerobot.utils.feature_utils import dataset_to_policy_features

    available = dataset_to_policy_features(features)
    problems = []
    for key, ft in {**policy_cfg.input_features, **policy_cfg.output_features}.items():
        if key not in available:
            problems.append(f"{key} (not in {source})")
        elif tuple(available[key].shape) != tuple(ft.shape):
            problems.append(
                f"{key} shape {tuple(ft.shape)} in the checkpoint vs {tuple(available[key].shape)} in {source}"
            )
    if problems:
        raise AdaDemoError(f"the checkpoint's features do not match {source}: " + "; ".join(problems))


def check_policy(path: str | Path, features: dict[str, dict], source: str = SUITE_FEATURES):
    """Refuse a checkpoint that is missing or does not match `features` (from `source`), reading only its config
    (the workers load the weights). Returns the config."""
    path = check_checkpoint_folder(path)
    cfg = read_policy_config(path)
    if cfg.type not in POLICY_TYPES:
        raise AdaDemoError(f"{path} holds a {cfg.type!r} policy; adademo supports {', '.join(POLICY_TYPES)}")
    check_policy_matches_features(cfg, features, source)
    return cfg


def check_readout(path: str | Path, readout: dict, folder: Path) -> None:
    """Refuse, in one line, a `readout` (values of READOUT_FIELDS) that the checkpoint at `path` cannot act by, or
    a `folder` that is not ours to write it into (`write_readout_policy`)."""
    import dataclasses

    path = check_checkpoint_folder(path)
    config = read_policy_config(path)
    given = ", ".join(f"--policy.{k}={v}" for k, v in readout.items())
    for name in readout:
        if name not in READOUT_FIELDS or not hasattr(config, name):
            raise AdaDemoError(f"--policy.{name}: a {config.type} policy has no such setting; drop the flag")
    steps = readout.get("n_action_steps", 1)
    if steps < 1:
        raise AdaDemoError(f"--policy.n_action_steps must be >= 1, got {steps}")
    if hasattr(config, "horizon"):  # Diffusion: LeRobot would run fewer without a word
        most = config.horizon - config.n_obs_steps + 1
        if steps > most:
            raise AdaDemoError(
                f"--policy.n_action_steps={steps}: this policy predicts {most} actions from the current step on "
                f"(horizon {config.horizon} - n_obs_steps {config.n_obs_steps} + 1); pass at most {most}"
            )
    try:
        dataclasses.replace(config, **readout)  # LeRobot's own checks (__post_init__) on the values
    except (ValueError, NotImplementedError) as e:
        raise AdaDemoError(f"{given}: {e}") from None
    if folder.is_symlink() or folder.exists() and not (folder / READOUT_RECORD).is_file():
        raise AdaDemoError(
            f"{folder} exists and is not a readout folder adademo-eval wrote; pick another --output_dir"
        )
    if folder.resolve() in (path.resolve(), *path.resolve().parents):
        raise AdaDemoError(f"--policy.path={path} is inside {folder}, which this evaluation rewrites")


def write_readout_policy(path: str | Path, readout: dict, folder: Path) -> Path:
    """The checkpoint at `path` acting by `readout` (checked by `check_readout`): `folder` gets its config.json
    with them, links to its other files (the weights are not copied) and READOUT_RECORD; a checkpoint that stock
    `lerobot-eval` loads too. Written beside `folder` and renamed into place. Returns `folder`."""
    import json
    import os
    import shutil

    path = Path(path)
    tmp = folder.with_name(folder.name + ".writing")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for f in path.iterdir():
        if f.name not in ("config.json", READOUT_RECORD):
            os.symlink(f.resolve(), tmp / f.name)
    stored = json.loads((path / "config.json").read_text())
    (tmp / "config.json").write_text(json.dumps(stored | readout, indent=4))
    (tmp / READOUT_RECORD).write_text(json.dumps({"from": str(path.resolve()), "readout": readout}, indent=2))
    # An earlier evaluation's (check_readout) is set aside whole first: a kill never leaves half of one.
    aside = folder.with_name(folder.name + ".replaced")
    shutil.rmtree(aside, ignore_errors=True)
    if folder.exists():
        folder.rename(aside)
    tmp.rename(folder)
    shutil.rmtree(aside, ignore_errors=True)
    return folder


def load_checked_policy(path: str | Path, features: dict[str, dict], device: str = "cpu") -> LoadedPolicy:
    """Load a checkpoint and refuse it unless it matches `features` (the suite's dataset features)."""
    path = check_checkpoint_folder(path)
    check_policy_matches_features(read_policy_config(path), features)
    return load_policy(path, device)
