"""`adademo-train`: LeRobot training with AdaDemo's episode-weighted sampler (paper principle C).

Longer than 400 lines: the config (LeRobot's, with our flags and refusals) and the few lines of LeRobot's
training loop we must own (listed in docs/lerobot-overrides.md) stay in one module, so every override of
LeRobot's training is in one place.

Everything but the sampler is LeRobot's: `make_dataset`, `make_policy`, the pre/post-processors, optimizer
presets, `update_policy` and `save_checkpoint`. LeRobot's training has no sampler hook, so this module holds the
few lines of the training loop that build the DataLoader around our `WeightedFrameSampler`.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.default import DatasetConfig
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.train import TrainPipelineConfig
from lerobot.configs.types import NormalizationMode
from tqdm import tqdm

from adademo_lerobot.core.errors import AdaDemoError, MachineError, machine_cause
from adademo_lerobot.core.files import check_writable_location
from adademo_lerobot.core.interrupts import HeldInterrupts, detach_from_group_signals
from adademo_lerobot.core.progress import show
from adademo_lerobot.core.threads import set_torch_threads
from adademo_lerobot.dataset.in_memory import InMemoryFrames, whole_batch
from adademo_lerobot.dataset.interventions import imitation_units, intervention_flags
from adademo_lerobot.dataset.layout import COL_SOURCE, POLICY_SOURCE
from adademo_lerobot.dataset.metadata import read_episode_metadata, try_load_suite_config
from adademo_lerobot.dataset.store import recover_unless_in_use
from adademo_lerobot.dataset.video import video_backend
from adademo_lerobot.evaluation.policy import (
    POLICY_TYPES,
    check_checkpoint_folder,
    check_policy_matches_features,
)
from adademo_lerobot.loop import lerobot_training
from adademo_lerobot.loop.configs import TrainCommandFlags
from adademo_lerobot.samplers import frame_weights, make_sampling_scheme
from adademo_lerobot.samplers.weighted_sampler import WeightedFrameSampler

log = logging.getLogger(__name__)
# Normalization floor: MetaWorld observations have constant dims (padding, unused objects); dividing by a
# near-zero std turns float noise at evaluation time into huge inputs.
MIN_STD = 1e-2
ADADEMO_TRAIN_INFO = "adademo_train.json"
SAVED_ON_INTERRUPT = "saved_on_interrupt"  # in ADADEMO_TRAIN_INFO: see `saved_on_interrupt`


# lerobot-train flags this training loop does not implement (it trains one policy on one local dataset, and
# evaluates with adademo-eval): given a value other than LeRobot's default, they are refused, never ignored.
NOT_IMPLEMENTED = (
    "env", "reward_model", "peft", "sample_weighting", "eval", "eval_steps", "max_eval_samples",
    "save_checkpoint", "save_checkpoint_to_hub", "rename_map", "job",
    "dataset.episodes", "dataset.streaming", "dataset.eval_split", "dataset.repo_type",
    *lerobot_training.NEWER_UNIMPLEMENTED_FLAGS,  # LeRobot main's --parallelism.*, --accelerator.*, ...
)  # fmt: skip


def _field_default(cls, name: str):
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def check_no_unimplemented_flags(cfg: TrainPipelineConfig) -> None:
    for path in NOT_IMPLEMENTED:
        owner, name = (cfg.dataset, path.split(".")[1]) if path.startswith("dataset.") else (cfg, path)
        value = getattr(owner, name)
        if value != _field_default(DatasetConfig if owner is cfg.dataset else TrainPipelineConfig, name):
            raise AdaDemoError(
                f"--{path} is a lerobot-train flag that adademo-train does not implement (got {value!r}); drop "
                "it (evaluate with adademo-eval; train on a subset with LeRobot's dataset tools first), or use "
                "lerobot-train"
            )


@dataclass
class TrainDatasetConfig(DatasetConfig):
    # LeRobot's default decoder choice logs a traceback when torchcodec cannot load; ours is quiet.
    video_backend: str = field(default_factory=video_backend)


@dataclass
class AdaDemoTrainConfig(TrainCommandFlags, TrainPipelineConfig):
    """LeRobot's training config, our flags (`TrainCommandFlags`) and defaults for a 2-core machine."""

    dataset: TrainDatasetConfig
    num_workers: int = 0
    batch_size: int = 64
    steps: int = 3000
    env_eval_freq: int = 0
    log_freq: int = 200
    save_freq: int = 1000

    def _save_pretrained(self, save_directory: Path) -> None:
        """LeRobot's `train_config.json` with LeRobot's fields only, so that stock `TrainPipelineConfig` reads it
        back (`lerobot-train --resume`); ours are in `adademo_train.json` beside it."""
        stock = TrainPipelineConfig.__new__(TrainPipelineConfig)  # the values are copied, not re-derived
        for f in dataclasses.fields(TrainPipelineConfig):
            setattr(stock, f.name, getattr(self, f.name))
        TrainPipelineConfig._save_pretrained(stock, save_directory)

    def use_pretrained_policy(self, path: str, overrides: list[str] | None = None) -> None:
        """Start from the checkpoint at `path` (`--policy.path`), its config changed by `overrides`
        (`--policy.dim_model=...`). The command line calls this; as a library, set `policy` and its
        `pretrained_path` yourself: nothing here reads the process's command line."""
        self.policy = pretrained_policy_config(path, overrides or [])

    def validate(self) -> None:
        if self.dataset.root is None:
            raise AdaDemoError("--dataset.root is required (the adademo dataset to train on)")
        check_no_unimplemented_flags(self)
        if self.steps < 1 or self.batch_size < 1:
            raise AdaDemoError(f"--steps and --batch_size must be >= 1 (got {self.steps}, {self.batch_size})")
        if self.save_freq < 1:
            raise AdaDemoError(
                f"--save_freq must be >= 1 (a checkpoint every that many steps; the last step is always saved), "
                f"got {self.save_freq}"
            )
        if self.output_dir is None:
            raise AdaDemoError("--output_dir is required")
        self.output_dir = Path(self.output_dir)
        check_writable_location(self.output_dir, "--output_dir")
        if self.resume:
            last = find_last_checkpoint(self.output_dir)
            if last is None:
                raise AdaDemoError(
                    f"--resume=true but {self.output_dir} has no complete checkpoint to resume from (stopped "
                    "before its first one: drop --resume=true, with another --output_dir or this one removed)"
                )
            self.checkpoint_path = last
            saved = json.loads((last / "training_state" / "training_step.json").read_text())
            if saved.get("batch_size", self.batch_size) != self.batch_size:  # the sampler resumes by it
                raise AdaDemoError(
                    f"{last} trained with --batch_size={saved['batch_size']}: resume with the same "
                    f"(got --batch_size={self.batch_size})"
                )
            device = self.policy.device if self.policy is not None else None
            self.policy = pretrained_policy_config(last / "pretrained_model")
            self.policy.device = device or self.policy.device
        elif self.output_dir.exists() and any(self.output_dir.iterdir()):
            raise AdaDemoError(
                f"--output_dir={self.output_dir} already exists: pass --resume=true to continue it or choose another"
            )
        elif self.policy is not None and self.policy.pretrained_path is not None:
            check_checkpoint_folder(self.policy.pretrained_path)
        if self.policy is None:
            raise AdaDemoError(
                "choose a policy: --policy.type=act|diffusion, or --policy.path=CKPT to fine-tune"
            )
        if self.policy.type not in POLICY_TYPES:
            raise AdaDemoError(
                f"unsupported --policy.type={self.policy.type!r}; choose one of {', '.join(POLICY_TYPES)}"
            )
        self.policy.push_to_hub = False
        # ENV features are not normalized by LeRobot's ACT/Diffusion by default; the task one-hot lives there. A
        # checkpoint fine-tuned keeps its own mapping: its weights learned the inputs as they were.
        if self.policy.pretrained_path is None:
            self.policy.normalization_mapping.setdefault("ENV", NormalizationMode.MEAN_STD)
        self.job_name = self.job_name or f"adademo_{self.policy.type}"
        if self.use_policy_training_preset:
            self.optimizer = self.policy.get_optimizer_preset()
            self.scheduler = self.policy.get_scheduler_preset()
        TrainCommandFlags.validate(self)
        if self.lr_schedule == "cosine":
            from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig

            lr = self.optimizer.lr
            self.scheduler = CosineDecayWithWarmupSchedulerConfig(
                num_warmup_steps=max(1, self.steps // 50),
                num_decay_steps=self.steps,
                peak_lr=lr,
                decay_lr=lr / 100,
            )


def pretrained_policy_config(path: str | Path, overrides: list[str] | None = None) -> PreTrainedConfig:
    """A checkpoint's policy config (with `--policy.*`-style overrides), marked to start from its weights."""
    path = check_checkpoint_folder(path)
    policy = PreTrainedConfig.from_pretrained(path, cli_overrides=list(overrides or []))
    policy.pretrained_path = path
    return policy


def find_last_checkpoint(output_dir: Path) -> Path | None:
    """The newest checkpoint whose weights and training state were both fully written."""
    candidates = []
    for d in (Path(output_dir) / "checkpoints").glob("[0-9]*"):
        # Only fully written checkpoints have a plain step name (see the save in `train`).
        if (
            d.name.isdigit()
            and (d / "pretrained_model" / "model.safetensors").exists()
            and (d / "training_state" / "training_step.json").exists()
        ):
            candidates.append(d)
    return max(candidates, key=lambda d: int(d.name)) if candidates else None


def robust_stats(stats: dict, keys: list[str]) -> dict:
    """Dataset stats with a floor on std and on the min-max range of low-dimensional features."""
    out = {k: dict(v) for k, v in stats.items()}
    for key in keys:
        s = out.get(key)
        if not s:
            continue
        if "std" in s:
            s["std"] = np.maximum(np.asarray(s["std"], dtype=np.float64), MIN_STD)
        if "min" in s and "max" in s:
            lo, hi = np.asarray(s["min"], np.float64), np.asarray(s["max"], np.float64)
            pad = np.maximum(MIN_STD - (hi - lo), 0) / 2
            s["min"], s["max"] = lo - pad, hi + pad
    return out


def save_whole_checkpoint(
    cfg, step, policy, optimizer, lr_scheduler, preprocessor, postprocessor, info, n
) -> None:
    """LeRobot's checkpoint, written beside its final name and renamed into place, so a kill never leaves a half
    checkpoint that looks complete (LeRobot writes training_step.json before the RNG and optimizer state)."""
    from lerobot.common.train_utils import get_step_checkpoint_dir, update_last_checkpoint

    checkpoint_dir = get_step_checkpoint_dir(cfg.output_dir, cfg.steps, step)
    partial = checkpoint_dir.with_name(checkpoint_dir.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        lerobot_training.save_checkpoint(
            partial, step, cfg, policy, optimizer, lr_scheduler, preprocessor, postprocessor, n
        )
        (partial / "pretrained_model" / ADADEMO_TRAIN_INFO).write_text(json.dumps(info, indent=2))
    except BaseException as err:  # a full disk: no half checkpoint left, `last` still names the previous one
        shutil.rmtree(partial, ignore_errors=True)
        if not isinstance(err, Exception):
            raise
        last = find_last_checkpoint(cfg.output_dir)
        cause, first = machine_cause(err)
        raise MachineError(
            f"writing the checkpoint of step {step} to {checkpoint_dir} failed ({cause[:200]}); "
            + (f"the last complete checkpoint is step {int(last.name)}" if last else "no checkpoint was kept")
            + f": {first}run the same command to continue from it (adademo-train: with --resume=true)"
        ) from err
    shutil.rmtree(checkpoint_dir, ignore_errors=True)
    os.replace(partial, checkpoint_dir)
    update_last_checkpoint(checkpoint_dir)
    for older in checkpoint_dir.parent.glob("[0-9]*"):  # saved on an interrupt, only to resume from
        if older.name.isdigit() and int(older.name) < step and saved_on_interrupt(older):
            # Renamed first: a kill during the removal leaves no half checkpoint under a step's name.
            older.rename(older.with_name(older.name + ".removing"))
    for removing in checkpoint_dir.parent.glob("*.removing"):
        shutil.rmtree(removing)


def saved_on_interrupt(checkpoint_dir: Path) -> bool:
    """A checkpoint written where Ctrl-C stopped the training (not at a `--save_freq` step): removed once a later
    one is written, so an interrupted and resumed training keeps the checkpoints of an uninterrupted one."""
    info = checkpoint_dir / "pretrained_model" / ADADEMO_TRAIN_INFO
    return info.exists() and bool(json.loads(info.read_text()).get(SAVED_ON_INTERRUPT))


def train(cfg: AdaDemoTrainConfig) -> Path:
    """Train (or fine-tune, or resume) and return the last checkpoint's `pretrained_model` folder.

    LeRobot's pieces throughout: its dataset, policy, processors, optimizer and scheduler, `update_policy` and
    checkpoints. Ours are the weighted loader (principle C) and the few lines of loop around `update_policy`."""
    from accelerate import Accelerator
    from accelerate.utils import DistributedDataParallelKwargs
    from lerobot.datasets.factory import make_dataset
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.utils.random_utils import set_seed

    cfg.validate()
    threads = set_torch_threads(cfg.torch_threads)
    if cfg.cudnn_deterministic:  # as lerobot-train does
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False
    root = Path(cfg.dataset.root)
    if not (root / "meta" / "info.json").exists():
        raise AdaDemoError(f"no LeRobot dataset at {root}")
    recover_unless_in_use(root, "adademo-train")
    episodes = read_episode_metadata(root)
    scheme = make_sampling_scheme(
        cfg.sampler, cfg.min_task_weight, episodes["task"].nunique(), cfg.sampler_alpha
    )
    if cfg.seed is not None:
        set_seed(cfg.seed)  # before the model is built: the same seed gives the same initial weights

    dataset = make_dataset(cfg)
    policy, preprocessor, postprocessor = build_policy(cfg, dataset)
    optimizer, lr_scheduler = make_optimizer_and_scheduler(cfg, policy)
    update_all_tensors_at_once(optimizer)
    # LeRobot's resume in its own two phases around `accelerator.prepare` (lerobot_training.py: 0.6.1 or main).
    step = lerobot_training.resume_before_prepare(cfg, optimizer, lr_scheduler) if cfg.resume else 0
    # The checkpoint's random state, given back once the batches start (`training_loop`): starting the loader
    # draws from it, which the interrupted run did once before its first step, not again at this one.
    resumed_rng = torch.get_rng_state() if cfg.resume else None
    if step >= cfg.steps:
        from lerobot.common.train_utils import update_last_checkpoint

        log.info("training already finished at step %d (%s)", step, cfg.output_dir)
        # The checkpoint resumed from, not `last`: a kill between renaming the final checkpoint into place and
        # moving the `last` link left the link on the one before.
        update_last_checkpoint(cfg.checkpoint_path)
        return cfg.output_dir / "checkpoints" / "last" / "pretrained_model"
    accelerator = Accelerator(
        cpu=policy.config.device == "cpu",
        step_scheduler_with_optimizer=False,
        kwargs_handlers=[DistributedDataParallelKwargs(find_unused_parameters=True)],
    )
    dataloader = weighted_loader(cfg, dataset, episodes, scheme, step, accelerator)
    policy, optimizer, dataloader, lr_scheduler = accelerator.prepare(
        policy, optimizer, dataloader, lr_scheduler
    )
    if cfg.resume:
        lerobot_training.resume_after_prepare(cfg, accelerator, policy, optimizer, lr_scheduler)
    flags = intervention_flags(root)  # LeRobot's DAgger data: who drove each frame
    kept_rollouts = bool((episodes[COL_SOURCE] == POLICY_SOURCE).any())  # --keep_successes
    suite_cfg = try_load_suite_config(
        root
    )  # training needs only LeRobot's format; the suite is recorded if known
    info = {
        "sampler": cfg.sampler,
        "min_task_weight": cfg.min_task_weight,
        "sampler_alpha": cfg.sampler_alpha,
        "lr_schedule": cfg.lr_schedule,
        "in_memory": cfg.in_memory,
        "torch_threads": threads,
        **({"autonomous_weight": cfg.autonomous_weight} if flags is not None or kept_rollouts else {}),
        "episodes": int(len(episodes)),
        "frames": int(dataset.num_frames),
        "episodes_per_task": {k: int(v) for k, v in episodes["task"].value_counts().items()},
        "suite": suite_cfg.to_dict() if suite_cfg else None,
    }
    parts = (policy, optimizer, lr_scheduler, preprocessor, postprocessor)
    mask = policy_action_mask(dataset, flags) if flags is not None and cfg.autonomous_weight == 0 else None
    return training_loop(cfg, dataset, dataloader, parts, accelerator, step, info, mask, resumed_rng)


def update_all_tensors_at_once(optimizer) -> None:
    """Adam and AdamW update every parameter tensor in one multi-tensor (`foreach`) call on CPU too. Left to
    torch's default (`foreach=None`), a CPU optimizer updates one tensor at a time in a Python loop: ~8 % of a
    small ACT's training step (benchmarks/results/train_speed.md). The foreach update does the same float
    operations (on CPU torch runs each foreach op as its per-tensor kernel in a C++ loop), so the weights come
    out bit for bit the same (tests/test_train.py).

    Its state dict keeps torch's default, so checkpoints resume in stock `lerobot-train` (whose loader wants the
    saved param groups' types to match a new optimizer's), and loading one sets the update back to at once."""
    if not isinstance(optimizer, torch.optim.Adam):  # AdamW too (ACT's preset; Diffusion's is Adam)
        return
    changed = [
        i
        for i, group in enumerate(optimizer.param_groups)
        if group.get("foreach") is None and all(p.device.type == "cpu" for p in group["params"])
    ]

    def at_once(optimizer) -> None:
        for i in changed:
            optimizer.param_groups[i]["foreach"] = True

    def as_torch_default(optimizer, state_dict: dict) -> dict:
        for i in changed:
            state_dict["param_groups"][i]["foreach"] = None
        return state_dict

    at_once(optimizer)
    optimizer.register_state_dict_post_hook(as_torch_default)
    optimizer.register_load_state_dict_post_hook(at_once)


def policy_action_mask(dataset, flags: np.ndarray):
    """For LeRobot's DAgger data, imitating the person's frames only: the steps of an action chunk that are the
    policy's own frames (after the person handed back) are marked as padding (`action_is_pad`), which ACT's loss
    leaves out (and Diffusion's with `--policy.do_mask_loss_for_padding=true`), as it does past an episode's end."""
    deltas = (dataset.reader.delta_indices or {}).get("action")
    if deltas is None:
        return None
    person = torch.as_tensor(flags, dtype=torch.bool)
    deltas = torch.as_tensor(deltas, dtype=torch.int64)

    def mask(batch: dict) -> None:
        if "action_is_pad" in batch:
            query = (batch["index"].reshape(-1, 1).to(torch.int64) + deltas).clamp(0, len(person) - 1)
            batch["action_is_pad"] = batch["action_is_pad"] | ~person[query]

    return mask


def build_policy(cfg: AdaDemoTrainConfig, dataset):
    """LeRobot's policy and processors for the dataset: normalized with the dataset's stats (with a floor on
    near-constant features), or a checkpoint's own processors when resuming."""
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    if cfg.policy.pretrained_path is not None:
        check_policy_matches_features(cfg.policy, dataset.meta.features, "the dataset")
    low_dim = [
        k
        for k, ft in dataset.meta.features.items()
        if k.startswith("observation") and ft["dtype"] == "float32"
    ]
    stats = robust_stats(dataset.meta.stats, [*low_dim, "action"])
    policy = make_policy(cfg=cfg.policy, ds_meta=dataset.meta)
    processor_kwargs: dict = {}
    if cfg.resume:
        pass  # the checkpoint's processors already hold the stats it was trained with
    elif cfg.policy.pretrained_path is not None:
        norm = {"stats": stats, "norm_map": policy.config.normalization_mapping}
        processor_kwargs["preprocessor_overrides"] = {
            "device_processor": {"device": policy.config.device},
            "normalizer_processor": {
                **norm,
                "features": {**policy.config.input_features, **policy.config.output_features},
            },
        }
        processor_kwargs["postprocessor_overrides"] = {
            "unnormalizer_processor": {**norm, "features": policy.config.output_features},
        }
    else:
        processor_kwargs["dataset_stats"] = stats
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=cfg.policy, pretrained_path=cfg.policy.pretrained_path, **processor_kwargs
    )
    return policy, preprocessor, postprocessor


def weighted_loader(cfg: AdaDemoTrainConfig, dataset, episodes, scheme, step: int, accelerator):
    """The DataLoader of principle C: frames drawn with the sampling scheme's episode weights, from where a
    resumed run stopped, batches from memory for datasets without camera frames. In LeRobot's DAgger data the
    units are the person's segments (and the policy's, with --autonomous_weight > 0)."""
    drop = int(getattr(cfg.policy, "drop_n_last_frames", 0) or 0)
    units = imitation_units(cfg.dataset.root, episodes, cfg.autonomous_weight)
    weights = frame_weights(scheme, units, dataset.num_frames, drop)
    # Under `accelerate launch` every process iterates the same draws and keeps every n-th batch
    # (accelerate's BatchSamplerShard), so the sampler draws n times the samples and skips n times as many.
    n = accelerator.num_processes
    sampler = WeightedFrameSampler(
        weights,
        num_samples=(cfg.steps - step) * cfg.batch_size * n,
        seed=cfg.seed or 0,
        skip=step * cfg.batch_size * n,
    )
    if cfg.in_memory and InMemoryFrames.supports(dataset):
        frames, loader_args = InMemoryFrames(dataset), {"collate_fn": whole_batch, "num_workers": 0}
        if cfg.num_workers > 0:
            log.warning(
                "--num_workers=%d is not used: the batches come from memory (--in_memory=false loads them with "
                "workers)", cfg.num_workers,
            )  # fmt: skip
    else:
        frames = dataset
        loader_args = {"num_workers": cfg.num_workers}
        if cfg.num_workers > 0:
            loader_args |= {
                "prefetch_factor": cfg.prefetch_factor,
                "persistent_workers": cfg.persistent_workers,
                "multiprocessing_context": cfg.dataloader_multiprocessing_context,
                "worker_init_fn": detach_from_group_signals,  # the training stops them (HeldInterrupts)
            }
    return torch.utils.data.DataLoader(
        frames,
        batch_size=cfg.batch_size,
        sampler=sampler,
        drop_last=False,
        pin_memory=accelerator.device.type == "cuda",
        **loader_args,
    )


def training_loop(
    cfg: AdaDemoTrainConfig,
    dataset,
    dataloader,
    parts,
    accelerator,
    step: int,
    info: dict,
    mask=None,
    resumed_rng: torch.Tensor | None = None,
) -> Path:
    """lerobot-train's loop around `update_policy` (metrics, wandb, checkpoints), for our loader; `mask` marks
    the action targets not to imitate (`policy_action_mask`); `resumed_rng`: torch's random state to train on
    from the first step (a resumed run's, as its checkpoint saved it)."""
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter

    policy, optimizer, lr_scheduler, preprocessor, postprocessor = parts
    metrics = {
        "loss": AverageMeter("loss", ":.3f"),
        "grad_norm": AverageMeter("grdn", ":.3f"),
        "lr": AverageMeter("lr", ":0.1e"),
        "update_s": AverageMeter("updt_s", ":.3f"),
        "dataloading_s": AverageMeter("data_s", ":.3f"),
    }
    tracker = lerobot_training.metrics_tracker(
        cfg.batch_size, dataset.num_frames, dataset.num_episodes, metrics, step, accelerator
    )
    wandb_logger = None
    if cfg.wandb.enable and cfg.wandb.project and accelerator.is_main_process:
        from lerobot.common.wandb_utils import WandBLogger

        wandb_logger = WandBLogger(cfg)

    camera_keys = dataset.meta.camera_keys
    policy.train()
    start, start_step = time.perf_counter(), step
    bar = tqdm(
        total=cfg.steps,
        initial=step,
        desc=f"train {cfg.policy.type}/{cfg.sampler}",
        unit="step",
        dynamic_ncols=True,
        disable=not accelerator.is_main_process,
    )
    data_start = time.perf_counter()
    # A first Ctrl-C (or SIGTERM) finishes the step and saves it, so a rerun loses no step; a second stops at once.
    with HeldInterrupts(enabled=accelerator.num_processes == 1) as held:
        for batch in dataloader:
            # After the loader's first batch, which drew its base seed from torch's generator (the interrupted
            # run drew it before its first step).
            if resumed_rng is not None:
                torch.set_rng_state(resumed_rng)
                resumed_rng = None
            # LeRobot's dataset returns frames as uint8 (stock lerobot-train converts them as this does).
            for key in camera_keys:
                if key in batch and batch[key].dtype == torch.uint8:
                    batch[key] = batch[key].to(torch.float32) / 255.0
            if mask is not None:
                mask(batch)
            batch = preprocessor(batch)
            tracker.dataloading_s = time.perf_counter() - data_start
            tracker, output = update_policy(
                tracker,
                policy,
                batch,
                optimizer,
                cfg.optimizer.grad_clip_norm,
                accelerator=accelerator,
                lr_scheduler=lr_scheduler,
            )
            step += 1
            tracker.step()
            bar.update(1)
            show(
                bar,
                loss=f"{tracker.loss.val:.3f}",
                steps_s=f"{(step - start_step) / (time.perf_counter() - start):.1f}",
            )
            if cfg.log_freq > 0 and step % cfg.log_freq == 0:
                if accelerator.is_main_process:
                    tqdm.write(str(tracker))  # to stdout, above the progress bar
                    if wandb_logger:
                        wandb_logger.log_dict({**tracker.to_dict(), **(output or {})}, step)
                tracker.reset_averages()
            scheduled, stop = step % cfg.save_freq == 0 or step == cfg.steps, held.requested
            if scheduled or stop:
                if accelerator.is_main_process:
                    save_whole_checkpoint(
                        cfg,
                        step,
                        accelerator.unwrap_model(policy),
                        optimizer,
                        lr_scheduler,
                        preprocessor,
                        postprocessor,
                        info if scheduled else {**info, SAVED_ON_INTERRUPT: True},
                        accelerator.num_processes,
                    )
                accelerator.wait_for_everyone()
            if step >= cfg.steps or stop:
                break
            data_start = time.perf_counter()
    bar.close()
    # At the last step too (its checkpoint is written): the command stops, as asked.
    if held.requested:
        log.info("stopped at step %d and saved it (%s)", step, find_last_checkpoint(cfg.output_dir))
        held.stop()
    elapsed = time.perf_counter() - start
    log.info(
        "trained %d steps in %.1f s (%.1f steps/s); checkpoint: %s",
        step - start_step, elapsed, (step - start_step) / max(elapsed, 1e-9),
        cfg.output_dir / "checkpoints" / "last" / "pretrained_model",
    )  # fmt: skip
    return cfg.output_dir / "checkpoints" / "last" / "pretrained_model"
