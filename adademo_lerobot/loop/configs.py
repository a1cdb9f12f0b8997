"""Dataclass configs shared by the commands (parsed by draccus, LeRobot-style dotted flags)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from adademo_lerobot.collectors import CollectorConfig, ScriptedCollectorConfig
from adademo_lerobot.collectors.takeover import DEMO_STARTS, TakeoverArgs, check_demo_start
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.metadata import has_dataset
from adademo_lerobot.evaluation.policy import READOUT_FIELDS
from adademo_lerobot.executors import ComputeArgs, ExecutionArgs, ThreadArgs
from adademo_lerobot.samplers import check_sampler_flags
from adademo_lerobot.strategies import StrategyConfig, default_strategy
from adademo_lerobot.suites import MetaWorldSuiteConfig, SuiteConfig

LR_SCHEDULES = ("preset", "cosine")
LEROBOT_CHOICE = "lerobot_choice"  # field metadata: the kind of LeRobot config the field holds


def lerobot_choice(kind: str) -> Any:
    """A field holding LeRobot's `kind` config ("policy", "robot" or "teleop"), chosen with `--FIELD.type=NAME`.

    LeRobot's config registries import torch (seconds), so the commands parse such a field as a plain dict
    first (`--help`, flag errors and `validate()` answer from that) and with LeRobot's type only afterwards
    (`adademo_lerobot.loop.cli`)."""
    return field(default=None, metadata={LEROBOT_CHOICE: kind})


@dataclass
class DatasetArgs:
    repo_id: str = "local/adademo"
    # Folder of the LeRobot dataset (required).
    root: str | None = None


def default_suite() -> SuiteConfig:
    return MetaWorldSuiteConfig()


def default_collector() -> CollectorConfig:
    return ScriptedCollectorConfig()


@dataclass
class CommitArgs:
    """The flag of every command that commits demonstrations to the dataset as it collects them."""

    # Demonstrations buffered in memory between dataset commits (a kill loses at most these).
    commit_every: int = 10

    def validate_commits(self) -> None:
        if self.commit_every < 1:
            raise AdaDemoError(f"--commit_every must be >= 1, got {self.commit_every}")


@dataclass
class CollectConfig(CommitArgs, ExecutionArgs):
    suite: SuiteConfig = field(default_factory=default_suite)
    collector: CollectorConfig = field(default_factory=default_collector)
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    # Demonstrations per task (a target: rerunning with --resume=true completes an interrupted collection).
    episodes_per_task: int = 10
    seed: int = 0
    resume: bool = False

    def validate(self) -> None:
        self.validate_commits()


@dataclass
class TrainSamplingArgs:
    # trajectory (AdaDemo C) | task (uniform over tasks) | tempered (n_k ** sampler_alpha) | frame (LeRobot's default)
    sampler: str = "trajectory"
    # Minimum share of every task under `trajectory` / `tempered`, in [0, 1/num_tasks].
    min_task_weight: float = 0.0
    # `tempered`: a task's share is proportional to (its trajectories) ** sampler_alpha (1: trajectory, 0: task).
    sampler_alpha: float = 1.0
    # Serve batches from tensors held in memory (datasets without camera frames); false: LeRobot's loading.
    in_memory: bool = True
    # `preset`: the policy's own learning-rate schedule (ACT: constant); `cosine`: a short warmup, then cosine
    # decay to a hundredth of the policy's learning rate at the last step (a steadier last checkpoint).
    lr_schedule: str = "preset"
    # Datasets whose frames carry LeRobot's `intervention` flag (`lerobot-rollout --strategy.type=dagger`): how
    # often the policy's own frames are drawn as imitation targets beside the person's (0: never; 1: as often).
    autonomous_weight: float = 0.0

    def validate(self) -> None:
        check_sampler_flags(self.sampler, self.sampler_alpha)
        if not 0.0 <= self.autonomous_weight < float("inf"):
            raise AdaDemoError(
                f"--autonomous_weight must be >= 0 (0: the policy's own frames are not imitated), got "
                f"{self.autonomous_weight}"
            )
        if self.lr_schedule not in LR_SCHEDULES:
            raise AdaDemoError(
                f"--lr_schedule must be one of {', '.join(LR_SCHEDULES)}, got {self.lr_schedule!r}"
            )


@dataclass
class TrainCommandFlags(TrainSamplingArgs, ThreadArgs):
    """adademo-train's own flags (and --torch_threads). Every flag of `lerobot-train` is accepted too:
    --dataset.repo_id/root, --policy.type or --policy.path, --output_dir, --steps, --batch_size, --resume,
    optimizer, scheduler, wandb, ... (`lerobot-train --help` lists them). Defaults that differ from lerobot-train:
    --steps=3000 --batch_size=64 --num_workers=0 --save_freq=1000 --env_eval_freq=0."""


@dataclass
class PolicyPathArgs:
    # A LeRobot checkpoint folder: .../checkpoints/last/pretrained_model (ACT or Diffusion).
    path: str | None = None


@dataclass
class EvalPolicyArgs(PolicyPathArgs):
    # How the checkpoint acts, over its config.json (stock lerobot-eval's flags of the same names); unset keeps the
    # checkpoint's. ACT's temporal ensembling: --policy.n_action_steps=1 --policy.temporal_ensemble_coeff=0.01.
    n_action_steps: int | None = None
    temporal_ensemble_coeff: float | None = None

    def readout(self) -> dict:
        """The readout settings given, by name."""
        return {f: getattr(self, f) for f in READOUT_FIELDS if getattr(self, f) is not None}


@dataclass
class EvalBatchArgs:
    # Episodes run side by side (one SyncVectorEnv); the policy sees a batch of this size.
    batch_size: int = 10


@dataclass
class EvalCommandConfig(ExecutionArgs):
    policy: EvalPolicyArgs = field(default_factory=EvalPolicyArgs)
    # The suite is rebuilt from the dataset (meta/adademo/suite.json; --suite.tasks picks a subset of its tasks);
    # without a dataset, from --suite.*.
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    suite: SuiteConfig = field(default_factory=default_suite)
    episodes_per_task: int = 10
    seed: int = 0
    output_dir: str | None = None
    eval: EvalBatchArgs = field(default_factory=EvalBatchArgs)


STEPS_SCHEDULES = ("constant", "proportional")


@dataclass
class RunTrainArgs(TrainSamplingArgs):
    # The policy to train: --train.policy.type=act|diffusion and the fields of LeRobot's ACTConfig or
    # DiffusionConfig (--train.policy.dim_model=64, ...). Optional with --policy.path (the checkpoint's own).
    policy: dict | None = lerobot_choice("policy")
    batch_size: int = 32
    # Steps of the round-0 training.
    steps: int = 2000
    # Later rounds: `scratch` retrains from scratch, `finetune` continues from the previous round's checkpoint.
    mode: str = "scratch"
    # scratch: `constant` steps, or `proportional` to the number of demonstrations (same passes over them).
    steps_schedule: str = "proportional"
    max_steps: int = 20000
    # finetune: steps per round.
    finetune_steps: int = 1000
    save_freq: int = 1000
    seed: int = 1000

    def validate(self) -> None:
        super().validate()
        if self.mode not in ("scratch", "finetune"):
            raise AdaDemoError(f"--train.mode must be scratch or finetune, got {self.mode!r}")
        if self.steps_schedule not in STEPS_SCHEDULES:
            raise AdaDemoError(f"--train.steps_schedule must be one of {', '.join(STEPS_SCHEDULES)}")


@dataclass
class RunEvalArgs:
    # The fixed evaluation set: this many initial states per task, the same every round and for every strategy.
    episodes_per_task: int = 20
    seed: int = 100
    batch_size: int = 10


# --plan_only's evaluation episodes per task, unless --plan_episodes_per_task says otherwise.
PLAN_EPISODES_PER_TASK = 20


@dataclass
class RoundArgs(CommitArgs, ExecutionArgs):
    """How an expansion round runs: adademo-expand's flags for its round and adademo-run's for each of its rounds
    (declared once: `RunConfig` hands them on as they are)."""

    # The expansion strategy and its settings: --strategy.type=adademo|budgeted|uniform|task_only, then its fields
    # (--strategy.target_successes=5, --strategy.budget=20, ...; `docs/commands/expand.md` lists them). A list
    # gives adademo-run one value per round (--strategy.budget=[32,48,64]; a single value serves every round).
    strategy: StrategyConfig = field(default_factory=default_strategy)
    seed: int = 0
    collector: CollectorConfig = field(default_factory=default_collector)
    # Where a demonstration starts: `initial` (the failed episode's initial state: the paper) or `takeover` (a
    # correction: the expert takes over the failed rollout at the step `--takeover.*` picks).
    demo_start: str = "initial"
    takeover: TakeoverArgs = field(default_factory=TakeoverArgs)
    # Keep the round's successful policy rollouts in the dataset too (`adademo/source=policy`; they cost no
    # episode the round did not run). Training draws them with --train.autonomous_weight (0: kept, not drawn).
    keep_successes: bool = False

    def validate_round(self) -> None:
        """The flags alone (answered before LeRobot is imported), whatever the number of rounds."""
        self.strategy.validate()
        check_demo_start(self.demo_start, self.takeover)
        if self.demo_start == "takeover" and not self.strategy.collects_at_failed_states:
            raise AdaDemoError(
                f"--demo_start=takeover corrects failed policy rollouts; --strategy.type={self.strategy.type} "
                "collects from fresh initial states without evaluating: use --strategy.type=adademo or budgeted, "
                "or --demo_start=initial"
            )
        if self.keep_successes and not self.strategy.needs_policy:
            raise AdaDemoError(
                f"--keep_successes keeps the round's successful policy rollouts; --strategy.type="
                f"{self.strategy.type} runs none: use a strategy that evaluates (adademo, budgeted, task_only) "
                "or drop --keep_successes"
            )
        self.validate_commits()
        self.validate_execution()


@dataclass
class ExpandConfig(RoundArgs):
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    # Evaluate and print the predicted demos per task (N_k = E/SR_k - E, capped, with the strategy's E and CAP)
    # without collecting (the strategies that predict so: adademo, and task_only without a budget).
    plan_only: bool = False
    # --plan_only: evaluation episodes per task that estimate SR_k.
    plan_episodes_per_task: int = PLAN_EPISODES_PER_TASK
    eval: EvalBatchArgs = field(default_factory=EvalBatchArgs)

    def validate(self) -> None:
        """adademo-expand's flags (answered before LeRobot is imported): one round, one value per setting."""
        self.validate_round()
        self.strategy.check_one_round()
        if self.plan_only and self.keep_successes:
            raise AdaDemoError(
                "--plan_only collects nothing, --keep_successes adds rollouts: pass one of them"
            )
        if self.plan_only and not self.strategy.can_plan():
            raise AdaDemoError(
                f"--plan_only predicts N_k = E/SR_k - E: it needs --strategy.type="
                f"{' or '.join(StrategyConfig.planning())} (task_only without --strategy.budget), not "
                f"{self.strategy.type}" + (" with a budget" if self.strategy.type == "task_only" else "")
            )
        if self.plan_episodes_per_task < 1:
            raise AdaDemoError(f"--plan_episodes_per_task must be >= 1, got {self.plan_episodes_per_task}")
        if not self.plan_only and self.plan_episodes_per_task != PLAN_EPISODES_PER_TASK:
            raise AdaDemoError(
                "--plan_episodes_per_task is used with --plan_only (task_only's own is "
                "--strategy.plan_episodes_per_task): add --plan_only, or drop it"
            )


@dataclass
class PushConfig:
    # The local adademo dataset (--dataset.root; --dataset.repo_id is not used for the push).
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    # Target repo on the hub: USER/NAME (or ORG/NAME).
    repo_id: str | None = None
    # Create the repo private (applies when the push creates it; an existing repo keeps its visibility).
    private: bool = False
    # Push to this branch (created from main if missing) instead of main.
    branch: str | None = None
    # License identifier written to the card.
    license: str = "apache-2.0"


@dataclass
class ReportConfig:
    run_dir: str | None = None
    # More run folders to compare against (e.g. the uniform and ablation arms).
    compare: list[str] = field(default_factory=list)
    # A Uniform run on the same tasks: the break-even rollout cost c* against it, in plain words.
    compare_to: str | None = None
    output_dir: str | None = None
    # A dataset instead of a run folder (one recorded on a robot: lerobot-record, lerobot-rollout's DAgger,
    # adademo-record): the person's work in it per round and task, printed (and report.md in --output_dir).
    dataset_root: str | None = None


JUDGES = ("auto", "keys", "teleop")


@dataclass
class RecordDatasetArgs:
    repo_id: str = "local/robot"
    # The dataset the policy was trained on (recorded with this robot); new episodes are appended to it.
    root: str | None = None
    # The longest a policy episode or a demonstration may run, in seconds (the person usually ends it sooner).
    episode_time_s: float = 60.0


@dataclass
class RecordConfig(ComputeArgs):
    # The robot: --robot.type=NAME and its fields, any robot lerobot-record knows or an installed plugin
    # (e.g. --robot.type=so101_follower --robot.port=/dev/ttyACM0; `lerobot-record --help` lists them).
    robot: dict | None = lerobot_choice("robot")
    # The person's teleoperator: --teleop.type=NAME and its fields (e.g. so101_leader).
    teleop: dict | None = lerobot_choice("teleop")
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    dataset: RecordDatasetArgs = field(default_factory=RecordDatasetArgs)
    # Tasks of this round, comma-separated (task strings of the dataset); default: every task of the dataset.
    tasks: str | None = None
    # The strategy and its settings, adademo-expand's (same flags, same defaults): --strategy.type=adademo (until E
    # successes or CAP demos per task: --strategy.target_successes, --strategy.max_demos_per_task, or
    # --strategy.budget) or budgeted (--strategy.budget=B demos in the round); `docs/commands/record.md`.
    strategy: StrategyConfig = field(default_factory=default_strategy)
    # Demonstrations tried per failure before moving on (each redo counts).
    max_attempts: int = 3
    # Who marks success and ends episodes: `keys` (the person), `teleop` (the teleoperator's events, e.g.
    # adademo_scripted), `auto` (teleop if it reports events, else keys).
    judge: str = "auto"
    # `initial`: a failure is answered by a demonstration from the failed episode's start (the paper);
    # `takeover`: the person may take over while the policy goes wrong (t, or the teleoperator's intervention
    # event) and the correction is recorded from there. Hold the leader arm where the follower is before taking
    # over (the follower moves to the leader's pose at once).
    demo_start: str = "initial"
    seed: int = 0

    # Flags of earlier releases and where they went (`adademo_lerobot.loop.cli` answers them in one line).
    MOVED_FLAGS: ClassVar[dict[str, str]] = {
        "target_successes": "strategy.target_successes",
        "max_demos_per_task": "strategy.max_demos_per_task",
        "max_eval_episodes_per_task": "strategy.max_eval_episodes_per_task",
    }

    def validate(self) -> None:
        """Checks of the flags alone (answered before LeRobot is imported: `adademo_lerobot.loop.cli`)."""
        if self.robot is None:
            raise AdaDemoError("--robot.type is required (the robot to record with, e.g. so101_follower)")
        if self.teleop is None:
            raise AdaDemoError("--teleop.type is required (the person's teleoperator, e.g. so101_leader)")
        if self.policy.path is None:
            raise AdaDemoError("--policy.path is required (the policy whose failures the round answers)")
        self.validate_threads()
        self.validate_device()
        self.strategy.validate()
        self.strategy.check_one_round("adademo-record")
        if (why := self.strategy.needs_a_simulator()) is not None:
            raise AdaDemoError(
                f"{why}, which needs a simulated round (adademo-expand, adademo-run); at a robot use "
                f"--strategy.type={' or '.join(StrategyConfig.running_with_a_person())} (budgeted with "
                "--strategy.rollout_cost=1 also buys demonstrations from new scenes; the person sets them up)"
            )
        if self.dataset.root is None or not has_dataset(self.dataset.root):
            raise AdaDemoError(
                f"no LeRobot dataset at --dataset.root={self.dataset.root} (the dataset the policy was trained on, "
                "recorded with this robot, e.g. by lerobot-record)"
            )
        if self.max_attempts < 1:
            raise AdaDemoError(f"--max_attempts must be >= 1, got {self.max_attempts}")
        if self.dataset.episode_time_s <= 0:
            raise AdaDemoError(f"--dataset.episode_time_s must be > 0, got {self.dataset.episode_time_s}")
        if self.judge not in JUDGES:
            raise AdaDemoError(f"--judge must be one of {', '.join(JUDGES)}, got {self.judge!r}")
        if self.demo_start not in DEMO_STARTS:
            raise AdaDemoError(
                f"unknown --demo_start={self.demo_start!r}; choose one of {', '.join(DEMO_STARTS)}"
            )
