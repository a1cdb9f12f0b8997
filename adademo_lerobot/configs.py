"""Dataclass configs shared by the commands (parsed by draccus, LeRobot-style dotted flags)."""

from __future__ import annotations

from dataclasses import dataclass, field

from adademo_lerobot.collectors import CollectorConfig, ScriptedCollectorConfig
from adademo_lerobot.executors import RayArgs
from adademo_lerobot.suites import MetaWorldSuiteConfig, SuiteConfig


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
class CollectConfig:
    suite: SuiteConfig = field(default_factory=default_suite)
    collector: CollectorConfig = field(default_factory=default_collector)
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    # Demonstrations per task (a target: rerunning with --resume=true completes an interrupted collection).
    episodes_per_task: int = 10
    seed: int = 0
    resume: bool = False
    # Episodes buffered in memory between dataset commits (a kill loses at most these).
    commit_every: int = 10
    # Where episodes run: `local` (this process) or `ray` (Ray actors; see --ray.*).
    executor: str = "local"
    ray: RayArgs = field(default_factory=RayArgs)


@dataclass
class PolicyPathArgs:
    # A LeRobot checkpoint folder: .../checkpoints/last/pretrained_model (ACT or Diffusion).
    path: str | None = None


@dataclass
class EvalBatchArgs:
    # Episodes run side by side (one SyncVectorEnv); the policy sees a batch of this size.
    batch_size: int = 10


@dataclass
class EvalCommandConfig:
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    # The suite is rebuilt from the dataset (meta/adademo/suite.json); without a dataset, from --suite.*.
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    suite: SuiteConfig = field(default_factory=default_suite)
    episodes_per_task: int = 10
    seed: int = 0
    output_dir: str | None = None
    eval: EvalBatchArgs = field(default_factory=EvalBatchArgs)
    device: str = "cpu"
    torch_threads: int = 2
    # Where episodes run: `local` (this process) or `ray` (Ray actors; see --ray.*).
    executor: str = "local"
    ray: RayArgs = field(default_factory=RayArgs)


@dataclass
class ExpandConfig:
    dataset: DatasetArgs = field(default_factory=DatasetArgs)
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    # adademo (principles A+B) | budgeted (A+B with a round budget) | uniform (the paper's baseline) |
    # task_only (ablation A)
    strategy: str = "adademo"
    # E: evaluation successes per task that end a task's collection (adademo; task_only's allocation).
    # Default 10; with --budget, picked so that the predicted total fits the budget.
    target_successes: int | None = None
    # B: demos in the round. budgeted: spent exactly; adademo/task_only: picks E; uniform: split evenly.
    budget: int | None = None
    # budgeted: weight of an earlier round's evaluation outcomes per round since (1: all count the same).
    posterior_decay: float = 0.5
    # CAP: at most this many new demos per task in this round (the paper's per-round cap).
    max_demos_per_task: int = 50
    # N: new demos per task for `uniform`.
    demos_per_task: int = 10
    # Bound on evaluation episodes per task so a task the expert cannot solve still ends (default 2 x (E + CAP)).
    max_eval_episodes_per_task: int | None = None
    # Evaluation episodes per task used to estimate SR_k (task_only, plan_only).
    plan_episodes_per_task: int = 20
    # Evaluate and print the predicted demos per task (N_k = E/SR_k - E, capped) without collecting.
    plan_only: bool = False
    seed: int = 0
    collector: CollectorConfig = field(default_factory=default_collector)
    eval: EvalBatchArgs = field(default_factory=EvalBatchArgs)
    device: str = "cpu"
    torch_threads: int = 2
    commit_every: int = 10
    # Where episodes run: `local` (this process) or `ray` (Ray actors; see --ray.*).
    executor: str = "local"
    ray: RayArgs = field(default_factory=RayArgs)


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
    output_dir: str | None = None
