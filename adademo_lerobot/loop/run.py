"""`adademo-run`: the whole of Algorithm 1 as one resumable command driven by a recipe.

    collect D_0 (E0 demos per task) -> train pi_0 -> evaluate on the fixed evaluation set
    for round i = 1..R:  expand (the strategy's round i) -> retrain (from scratch or fine-tune) -> evaluate
    report

With `--dataset.repo_id` (and optionally `--policy.path`) the run starts from what the user has instead: their
dataset (a copy, by default) replaces the collection and their checkpoint the round-0 training; the dataset's
earlier rounds are kept and the run's round i is the dataset's round base + i (`adademo_lerobot.loop.start`).

Every stage is itself resumable (collection, training checkpoints, the expansion journal) and the run marks
finished stages in `RUN_DIR/run_state.json`, so rerunning the same command after an interruption continues
where it stopped without redoing finished stages. The fixed evaluation set (seeds under the "eval" key) is the
same for every round and every strategy and is never used for expansion.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from adademo_lerobot.collectors.takeover import check_can_take_over
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import atomic_write_text, check_writable_location, exclusive_use
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.layout import POLICY_SOURCE
from adademo_lerobot.dataset.ledger import ledger_rounds
from adademo_lerobot.dataset.metadata import has_dataset, read_episode_metadata
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.evaluation.policy import check_policy
from adademo_lerobot.evaluation.rollouts import format_success_table, success_table, write_eval_outputs
from adademo_lerobot.executors import make_executor
from adademo_lerobot.loop.collect import collect_initial_demos, format_collection_table
from adademo_lerobot.loop.configs import (
    DatasetArgs,
    EvalBatchArgs,
    ExpandConfig,
    PolicyPathArgs,
    RoundArgs,
    RunEvalArgs,
    RunTrainArgs,
    TrainSamplingArgs,
    default_suite,
)
from adademo_lerobot.loop.evaluate import evaluate_fixed_set
from adademo_lerobot.loop.expand import finish_stale_journals, next_round, run_expand
from adademo_lerobot.loop.run_state import RunData, RunState, saved_stage
from adademo_lerobot.loop.start import (
    Start,
    StartDatasetArgs,
    StartPolicyArgs,
    check_start,
    combined_digest,
    prepare_dataset,
)
from adademo_lerobot.samplers import make_sampling_scheme
from adademo_lerobot.suites import SuiteConfig, TaskSuite, make_suite, suite_config_from_dict


@dataclass
class RunConfig(RoundArgs):
    """The run's own flags; those of its expansion rounds (strategy, collector, demo start, execution, ...) are
    `RoundArgs`, adademo-expand's, handed on as they are."""

    run_dir: str | None = None
    # Start from an existing dataset (no round-0 collection) and, optionally, checkpoint (no round-0 training).
    dataset: StartDatasetArgs = field(default_factory=StartDatasetArgs)
    policy: StartPolicyArgs = field(default_factory=StartPolicyArgs)
    suite: SuiteConfig = field(default_factory=default_suite)
    # E0: demos per task in the initial dataset.
    initial_demos_per_task: int = 10
    rounds: int = 2
    train: RunTrainArgs = field(default_factory=RunTrainArgs)
    eval: RunEvalArgs = field(default_factory=RunEvalArgs)
    # Push the final dataset to the hub as hub_repo_id (token from HF_TOKEN or your login).
    push_to_hub: bool = False
    hub_repo_id: str | None = None
    hub_private: bool = False

    def validate(self) -> None:
        """Checks of the flags alone (answered before LeRobot is imported: `adademo_lerobot.loop.cli`)."""
        if self.run_dir is None:
            raise AdaDemoError("--run_dir is required (everything of the run goes there)")
        if self.rounds < 0 or self.initial_demos_per_task < 1:
            raise AdaDemoError("--rounds must be >= 0 and --initial_demos_per_task >= 1")
        if self.eval.episodes_per_task < 1 or self.eval.batch_size < 1:
            raise AdaDemoError(
                f"--eval.episodes_per_task and --eval.batch_size must be >= 1, got {self.eval.episodes_per_task} "
                f"and {self.eval.batch_size}"
            )
        self.validate_round()  # the strategy, demo start and execution flags
        if self.dataset.root is not None and self.dataset.repo_id is None:
            self.dataset.repo_id = f"local/{Path(self.dataset.root).name}"
        if self.policy.path is not None and self.dataset.repo_id is None:
            raise AdaDemoError(
                "--policy.path needs the dataset to continue: --dataset.repo_id=USER/NAME (a hub dataset) or "
                "--dataset.root=FOLDER (a local one)"
            )
        if self.dataset.revision is not None and self.dataset.root is not None:
            raise AdaDemoError(
                "--dataset.revision picks a hub revision; a local --dataset.root has none: drop one"
            )
        if self.train.policy is None and self.policy.path is None:
            raise AdaDemoError(
                "the recipe needs train.policy (e.g. --train.policy.type=act), or start from a checkpoint with "
                "--policy.path=CKPT"
            )
        if self.push_to_hub and not self.hub_repo_id:
            raise AdaDemoError("--push_to_hub=true needs --hub_repo_id=USER/NAME")
        self.train.validate()

    def expand_config(self, dataset_root: Path, repo_id: str, checkpoint: Path) -> ExpandConfig:
        """An expansion round of the run, as adademo-expand would run it (`run_expand` picks the strategy's
        round-i values)."""
        return ExpandConfig(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(RoundArgs)},
            dataset=DatasetArgs(repo_id=repo_id, root=str(dataset_root)),
            policy=PolicyPathArgs(path=str(checkpoint)),
            eval=EvalBatchArgs(batch_size=self.eval.batch_size),
        )


def run_settings(cfg: RunConfig, suite: dict) -> dict:
    """What defines the run, kept in run_state.json (FIXED_SETTINGS among them must not change on resume)."""
    return {
        "suite": suite,
        "strategy": cfg.strategy.to_dict(),
        "collector": cfg.collector.to_dict(),
        "rounds": cfg.rounds,
        "initial_demos_per_task": cfg.initial_demos_per_task,
        "seed": cfg.seed,
        "eval": {"episodes_per_task": cfg.eval.episodes_per_task, "seed": cfg.eval.seed},
        "sampler": cfg.train.sampler,
        "policy_type": cfg.train.policy.type if cfg.train.policy else None,
        "train_mode": cfg.train.mode,
        "min_task_weight": cfg.train.min_task_weight,
        "train_seed": cfg.train.seed,
        "batch_size": cfg.train.batch_size,
        "autonomous_weight": cfg.train.autonomous_weight,
        "sampler_alpha": cfg.train.sampler_alpha,
        "lr_schedule": cfg.train.lr_schedule,
        "demo_start": cfg.demo_start,
        "takeover": cfg.takeover.to_dict() if cfg.demo_start == "takeover" else None,
        **({"keep_successes": True} if cfg.keep_successes else {}),
        "start": None
        if cfg.dataset.repo_id is None
        else {
            "dataset": {k: getattr(cfg.dataset, k) for k in ("repo_id", "root", "revision", "copy")},
            "policy": {k: getattr(cfg.policy, k) for k in ("path", "revision")},
        },
    }


def run(cfg: RunConfig, on_ledger_written: Callable[[int], None] | None = None) -> Path:
    """Algorithm 1 end to end. Every stage is run through `state.stage`, which skips a stage a previous
    invocation finished (and returns its result): rerunning the command resumes. `on_ledger_written`: as in
    `run_expand`, for every expansion round."""
    cfg.validate()
    run_dir = Path(cfg.run_dir)
    suite, start = checked_suite_and_start(cfg, run_dir)  # everything refused before anything is written
    run_dir.mkdir(parents=True, exist_ok=True)
    with exclusive_use(run_dir, "adademo-run"), Episodes(cfg, suite) as episodes:
        state = RunState(run_dir, run_settings(cfg, suite.config.to_dict()), on_stage=print)
        if cfg.dataset.repo_id is not None:  # the user's data
            data = RunData.of_stage(state.stage("start", begin_from, cfg, start, run_dir))
        else:
            data = RunData.collected(run_dir)
            state.stage("collect", collect_initial, cfg, suite, episodes, data.root, data.repo_id)
        checkpoint = data.checkpoint or Path(state.stage("train-0", train_round, cfg, run_dir, data, 0))
        state.stage("eval-0", evaluate_round, cfg, suite, episodes, run_dir, checkpoint, 0)
        for i in range(1, cfg.rounds + 1):
            state.stage(f"expand-{i}", expand_round, cfg, episodes, data, checkpoint, i, on_ledger_written)
            checkpoint = Path(state.stage(f"train-{i}", train_round, cfg, run_dir, data, i, checkpoint))
            state.stage(f"eval-{i}", evaluate_round, cfg, suite, episodes, run_dir, checkpoint, i)
        from adademo_lerobot.loop.report import write_report

        report = write_report([run_dir], run_dir / "report")
        if cfg.push_to_hub:
            state.stage("push", push, cfg, data.root, data.repo_id)
    print(f"run complete: {run_dir} (report: {report})")
    return run_dir


def checked_suite_and_start(cfg: RunConfig, run_dir: Path) -> tuple[TaskSuite, Start | None]:
    """The run's suite and, for a run that starts from the user's dataset and checkpoint, where it starts: all
    checked before the run folder is made. A resumed run keeps the suite it started with."""
    check_writable_location(run_dir, "--run_dir")
    start, started = None, saved_stage(run_dir, "start")
    if cfg.dataset.repo_id is not None and started is None:
        start = check_start(
            cfg.dataset,
            cfg.policy,
            cfg.suite,
            cfg.suite == default_suite(),
            cfg.train.policy,
            finetune=cfg.train.mode == "finetune",
        )
        suite_config = start.suite_config
    elif started is not None:
        suite_config = suite_config_from_dict(started["settings"]["suite"])
    else:
        suite_config = cfg.suite
    suite = make_suite(suite_config)
    cfg.collector.validate(suite)
    if cfg.demo_start == "takeover":
        check_can_take_over(suite, cfg.collector)
    make_sampling_scheme(
        cfg.train.sampler, cfg.train.min_task_weight, len(suite.tasks), cfg.train.sampler_alpha
    )
    if cfg.train.policy is None and started is not None and started["result"]["checkpoint"]:
        set_policy_from_checkpoint(cfg, Path(started["result"]["checkpoint"]))
    elif cfg.train.policy is None and start is not None:
        set_policy_from_checkpoint(cfg, start.checkpoint)
    return suite, start


def set_policy_from_checkpoint(cfg: RunConfig, checkpoint: Path) -> None:
    """No policy in the recipe: later rounds train the checkpoint's own architecture (from scratch, or from the
    previous round with finetune)."""
    from lerobot.configs.policies import PreTrainedConfig

    cfg.train.policy = PreTrainedConfig.from_pretrained(checkpoint)
    cfg.train.policy.pretrained_path = None


class Episodes:
    """The run's executor, made on first use (a resumed run that only trains starts no Ray), closed at the end."""

    def __init__(self, cfg: RunConfig, suite):
        self.cfg, self.suite, self._executor = cfg, suite, None

    def get(self):
        if self._executor is None:
            self._executor = make_executor(self.cfg, self.suite, self.cfg.collector, self.cfg.eval.batch_size)
        return self._executor

    def __enter__(self) -> Episodes:
        return self

    def __exit__(self, *exc) -> None:
        if self._executor is not None:
            self._executor.close()


def begin_from(cfg: RunConfig, start: Start, run_dir: Path) -> dict:
    """The run's dataset (a copy of the user's, or theirs in place), the round its history ends at, the given
    checkpoint, and where all of it came from (recorded in run_state.json and origin.json)."""
    root, digests = prepare_dataset(start, cfg.dataset.copy, run_dir / "dataset")
    origin = {**start.origin(cfg.dataset, cfg.policy), "files": digests}
    atomic_write_text(run_dir / "origin.json", json.dumps(origin, indent=2))
    base = next_round(root) - 1
    eps = read_episode_metadata(root)
    print(
        f"starting from {cfg.dataset.repo_id}: {len(eps)} episodes ("
        + ", ".join(f"{t} {n}" for t, n in eps.groupby("task").size().items())
        + f"), rounds 0..{base}; "
        + (f"checkpoint {start.checkpoint}" if start.checkpoint else "round 0 trains a policy on it")
    )
    return {
        "dataset_root": str(root),
        "repo_id": cfg.dataset.repo_id,
        "base_round": base,
        "checkpoint": str(start.checkpoint) if start.checkpoint else None,
        "origin": {k: v for k, v in origin.items() if k != "files"},
        "dataset_digest": combined_digest(digests),
    }


def collect_initial(cfg: RunConfig, suite, episodes: Episodes, dataset_root: Path, repo_id: str) -> dict:
    if not has_dataset(dataset_root):
        DemoDataset.check_new_root(dataset_root)
        dataset = DemoDataset(repo_id, dataset_root, suite.config)
    else:
        dataset = DemoDataset.open(repo_id, dataset_root)
    records = collect_initial_demos(
        suite, dataset, cfg.initial_demos_per_task, cfg.seed, cfg.collector, episodes.get(), cfg.commit_every
    )
    print(format_collection_table(records, dataset_root))
    return {t: r.demos_added for t, r in records.items()}


def train_round(cfg: RunConfig, run_dir: Path, data: RunData, i: int, previous: Path | None = None) -> str:
    """Round i's policy: from scratch, or (finetune) from the previous round's checkpoint `previous`. The
    proportional schedule counts steps against the data of round 0 (the dataset's history before the run)."""
    from lerobot.configs.policies import PreTrainedConfig

    from adademo_lerobot.loop.train import AdaDemoTrainConfig, TrainDatasetConfig, find_last_checkpoint, train

    out = run_dir / "train" / f"round-{i}"
    resume = find_last_checkpoint(out) is not None
    if out.exists() and not resume:
        shutil.rmtree(out)  # killed before its first checkpoint: nothing to keep
    policy = copy.deepcopy(cfg.train.policy)
    policy.device = cfg.device
    steps = cfg.train.steps
    if i > 0 and cfg.train.mode == "finetune":
        policy = PreTrainedConfig.from_pretrained(previous)
        policy.pretrained_path = previous
        policy.device = cfg.device
        steps = cfg.train.finetune_steps
    elif i > 0 and cfg.train.steps_schedule == "proportional":
        eps = read_episode_metadata(data.root)
        initial = int((eps["adademo/round"] <= data.base_round).sum())
        # Kept policy rollouts (--keep_successes) count as the share of a demonstration training draws them at.
        kept = int(
            ((eps["adademo/round"] > data.base_round) & (eps["adademo/source"] == POLICY_SOURCE)).sum()
        )
        trained_on = len(eps) - kept * (1 - cfg.train.autonomous_weight)
        steps = min(cfg.train.max_steps, round(cfg.train.steps * trained_on / max(initial, 1)))
    train_cfg = AdaDemoTrainConfig(
        dataset=TrainDatasetConfig(repo_id=data.repo_id, root=str(data.root)),
        policy=policy,
        output_dir=out,
        resume=resume,
        seed=cfg.train.seed,
        batch_size=cfg.train.batch_size,
        steps=steps,
        save_freq=min(cfg.train.save_freq, steps),
        torch_threads=cfg.torch_threads,
        # the flags adademo-train shares with the recipe's train section (sampler, schedule, ...)
        **{f.name: getattr(cfg.train, f.name) for f in dataclasses.fields(TrainSamplingArgs)},
    )
    return str(train(train_cfg).resolve())


def evaluate_round(
    cfg: RunConfig, suite, episodes: Episodes, run_dir: Path, checkpoint: Path, i: int
) -> dict:
    check_policy(checkpoint, dataset_features(suite))
    executor = episodes.get()
    executor.use_policy(str(checkpoint))
    records, env_steps, seconds = evaluate_fixed_set(
        suite, executor, cfg.eval.seed, cfg.eval.episodes_per_task
    )
    table = success_table(records, suite.tasks)
    print(f"round {i} evaluation (fixed set, {cfg.eval.episodes_per_task} episodes per task):")
    print(format_success_table(table))
    out = run_dir / "eval" / f"round-{i:03d}"
    write_eval_outputs(
        out,
        records,
        table,
        {"round": i, "policy_path": str(checkpoint), "env_steps": env_steps, "wall_seconds": seconds},
    )
    return {"average_success": float(table.success_rate.iloc[-1])}


def expand_round(
    cfg: RunConfig,
    episodes: Episodes,
    data: RunData,
    checkpoint: Path,
    i: int,
    on_ledger_written: Callable[[int], None] | None = None,
) -> dict:
    """The run's expansion round i, the dataset's round base + i (after its earlier rounds): the one truth
    handed to `run_expand`."""
    r = data.base_round + i
    if r in ledger_rounds(data.root):  # killed after the round finished, before the run marked it done
        finish_stale_journals(data.root)  # and maybe before its journal was archived
        eps = read_episode_metadata(data.root)
        return {"demos_added": eps[eps["adademo/round"] == r].groupby("task").size().astype(int).to_dict()}
    expand_cfg = cfg.expand_config(data.root, data.repo_id, checkpoint)
    records = run_expand(
        expand_cfg,
        round_in_run=i,
        round_index=r,
        executor=episodes.get(),
        on_ledger_written=on_ledger_written,
    )
    return {"demos_added": {r.task: r.demos_added for r in records}}


def push(cfg: RunConfig, dataset_root: Path, repo_id: str) -> dict:
    from adademo_lerobot.loop.push import PushConfig, run_push

    push_cfg = PushConfig()
    push_cfg.dataset.root, push_cfg.dataset.repo_id = str(dataset_root), repo_id
    push_cfg.repo_id, push_cfg.private = cfg.hub_repo_id, cfg.hub_private
    run_push(push_cfg)
    return {"repo_id": cfg.hub_repo_id}
