"""LeRobot's checkpoint save, training-state resume and metrics tracker, for both of LeRobot's training APIs.

- LeRobot 0.6.1: `save_checkpoint(..., num_processes=, batch_size=)`, and `load_training_state` restores the step,
  RNG, optimizer and scheduler before `accelerator.prepare`; `MetricsTracker(..., accelerator=)`.
- LeRobot main after 0.6.1 (PR #4010, its parallel-training engine; unreleased): `save_checkpoint(...,
  accelerator=)` records the topology from `cfg.parallelism`; resuming is two-phase, `resume_before_prepare` (step
  and RNG) then `resume_after_prepare` (optimizer and scheduler, into the prepared objects);
  `MetricsTracker(..., dp_world_size=)`.

Which API is installed is decided here, once, from the names `lerobot.common.train_utils` provides; `train.py`
calls only these functions. See docs/lerobot-overrides.md.
"""

from __future__ import annotations

import dataclasses
import functools

from lerobot.configs.default import DatasetConfig
from lerobot.configs.train import TrainPipelineConfig


@functools.cache
def two_phase_resume() -> bool:
    """Whether the installed LeRobot has LeRobot main's training API (PR #4010) rather than 0.6.1's."""
    from lerobot.common import train_utils

    return hasattr(train_utils, "resume_before_prepare")


# lerobot-train flags added after 0.6.1 that adademo-train does not implement (it builds its own Accelerator and
# samples every episode): train.py refuses them like its other NOT_IMPLEMENTED flags, where they exist.
_NEWER_FLAGS = ("parallelism", "accelerator", "checkpoint_format", "ema", "dataset.exclude_episodes")
_INSTALLED_FLAGS = {f.name for f in dataclasses.fields(TrainPipelineConfig)} | {
    f"dataset.{f.name}" for f in dataclasses.fields(DatasetConfig)
}
NEWER_UNIMPLEMENTED_FLAGS = tuple(path for path in _NEWER_FLAGS if path in _INSTALLED_FLAGS)


def _resolve_topology(cfg) -> None:
    # As LeRobot main's own make_accelerator does (idempotent): the world size recorded in training_step.json and
    # compared on resume is cfg.parallelism's, which is only filled in here (our loop builds its own Accelerator).
    from lerobot.configs.parallelism import world_size_from_env

    cfg.parallelism.resolve(world_size_from_env())


def save_checkpoint(
    checkpoint_dir, step, cfg, policy, optimizer, scheduler, preprocessor, postprocessor, num_processes
) -> None:
    """LeRobot's `save_checkpoint` into `checkpoint_dir`, from the main process only, `policy` unwrapped."""
    from lerobot.common import train_utils

    if not two_phase_resume():
        train_utils.save_checkpoint(
            checkpoint_dir, step, cfg, policy, optimizer, scheduler, preprocessor, postprocessor,
            num_processes=num_processes, batch_size=cfg.batch_size,
        )  # fmt: skip
        return
    _resolve_topology(cfg)
    # No accelerator: with one, LeRobot waits at a barrier for processes that do not save (ours is rank 0 only);
    # unsharded, it is only used to unwrap the policy, which the caller did.
    train_utils.save_checkpoint(
        checkpoint_dir, step, cfg, policy, optimizer, scheduler, preprocessor, postprocessor
    )


def resume_before_prepare(cfg, optimizer, scheduler) -> int:
    """The step of `cfg.checkpoint_path`, its RNG state restored (and with 0.6.1 its optimizer and scheduler state,
    loaded in place, as 0.6.1's lerobot-train does); call before `accelerator.prepare`."""
    from lerobot.common import train_utils

    if not two_phase_resume():
        step, _, _ = train_utils.load_training_state(cfg.checkpoint_path, optimizer, scheduler)
        return step
    _resolve_topology(cfg)
    return train_utils.resume_before_prepare(cfg)


def resume_after_prepare(cfg, accelerator, policy, optimizer, scheduler) -> None:
    """The rest of the resume, after `accelerator.prepare`: with LeRobot main the optimizer and scheduler state,
    loaded into the prepared objects (its order); nothing left with 0.6.1."""
    if two_phase_resume():
        from lerobot.common import train_utils

        train_utils.resume_after_prepare(cfg, accelerator, policy, optimizer, scheduler)


def metrics_tracker(batch_size, num_frames, num_episodes, metrics, initial_step, accelerator):
    """LeRobot's `MetricsTracker`, counting samples over every process."""
    from lerobot.utils.logging_utils import MetricsTracker

    world = (
        {"dp_world_size": accelerator.num_processes} if two_phase_resume() else {"accelerator": accelerator}
    )
    return MetricsTracker(batch_size, num_frames, num_episodes, metrics, initial_step=initial_step, **world)
