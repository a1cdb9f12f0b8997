"""The fixed evaluation set: `adademo-eval`, and `adademo-run`'s evaluation after every round.

`episodes_per_task` initial states per task from `seed` under a key collection never uses, the same every round
and for every strategy. They are cut into batches of `--eval.batch_size` (always the same batches, so the same
results on any executor); every batch is handed to the executor at once and read back in order.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from adademo_lerobot.collectors import ScriptedCollectorConfig
from adademo_lerobot.core.episodes import EpisodeRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import check_writable_location
from adademo_lerobot.core.progress import show
from adademo_lerobot.core.seeds import evaluation_seeds
from adademo_lerobot.evaluation.rollouts import format_success_table, success_table, write_eval_outputs
from adademo_lerobot.executors import Executor, make_executor
from adademo_lerobot.suites import SuiteConfig, TaskSuite
from adademo_lerobot.suites.base import split_task_list


def evaluate_fixed_set(
    suite: TaskSuite, executor: Executor, seed: int, episodes_per_task: int, tasks: list[str] | None = None
) -> tuple[list[EpisodeRecord], int, float]:
    """Every task (or `tasks`, a subset) on its fixed evaluation states, with one progress bar over episodes
    (the executor already has the policy). Returns (records, env steps, wall seconds)."""
    start = time.perf_counter()
    tasks = suite.tasks if tasks is None else tasks
    units = []
    for task in tasks:
        seeds = evaluation_seeds(seed, task, episodes_per_task)
        for begin in range(0, len(seeds), executor.batch_size):
            units.append((task, executor.evaluate(task, seeds[begin : begin + executor.batch_size])))
    records: list[EpisodeRecord] = []
    with tqdm(
        total=len(tasks) * episodes_per_task, desc="evaluating", unit="episode", dynamic_ncols=True
    ) as bar:
        for task, pending in units:
            batch = pending.result()
            records += batch
            bar.update(len(batch))
            done = [r for r in records if r.task == task]
            show(bar, task=task, success=f"{sum(r.success for r in done) / len(done):.0%}")
    return records, sum(r.steps for r in records), time.perf_counter() - start


def suite_to_evaluate(dataset_root: str | None, flags: SuiteConfig) -> tuple[SuiteConfig, list[str]]:
    """The suite and the tasks `adademo-eval` evaluates. Without a dataset: the suite flags. With one: the
    dataset's suite (its task list is the policy's one-hot), where `--suite.tasks` picks a subset of its tasks and
    `--suite.max_episode_steps` sets the evaluation's step limit; any other suite flag that contradicts the
    dataset is refused, never ignored."""
    from adademo_lerobot.dataset.metadata import load_suite_config
    from adademo_lerobot.suites import make_suite

    if dataset_root is None:
        return flags, make_suite(flags).tasks
    stored = load_suite_config(Path(dataset_root))
    stored_tasks = split_task_list(stored.tasks)
    defaults = type(flags)()
    given = {f.name for f in dataclasses.fields(flags) if getattr(flags, f.name) != getattr(defaults, f.name)}
    # Flags every suite has (tasks, step limit) given without --suite.type are read in the dataset's suite.
    picks_only = given <= {"tasks", "max_episode_steps"}
    if flags.type != stored.type and not (picks_only and flags.type == SuiteConfig.default_choice_name()):
        raise AdaDemoError(
            f"--suite.type={flags.type} but the dataset's suite is {stored.type}: drop --suite.type (the suite "
            "comes from the dataset)"
        )
    tasks = stored_tasks
    if "tasks" in given:
        # In the dataset's suite, so that short names (Adroit's `hammer`) and groups (`mt10`) pick its tasks.
        tasks = split_task_list(dataclasses.replace(stored, tasks=flags.tasks).canonical().tasks)
        unknown = [t for t in tasks if t not in stored_tasks]
        if unknown or not tasks:
            raise AdaDemoError(
                f"--suite.tasks: {', '.join(unknown) or 'no task'} not in the dataset's tasks "
                f"({', '.join(stored_tasks)}); pass a subset of those"
            )
    if "max_episode_steps" in given:
        stored.max_episode_steps = flags.max_episode_steps
    for name in sorted(given - {"tasks", "max_episode_steps"}):
        if getattr(flags, name) != getattr(stored, name, None):
            raise AdaDemoError(
                f"--suite.{name}={getattr(flags, name)} contradicts the dataset's suite "
                f"({name}={getattr(stored, name, None)!r}); drop the flag (with --dataset.root the suite comes "
                "from the dataset; --suite.tasks and --suite.max_episode_steps may still be set)"
            )
    return stored, tasks


def run_eval(cfg) -> pd.DataFrame:
    """`adademo-eval`."""
    from adademo_lerobot.dataset.features import dataset_features
    from adademo_lerobot.evaluation.policy import check_policy, check_readout, write_readout_policy
    from adademo_lerobot.suites import make_suite

    if cfg.policy.path is None:
        raise AdaDemoError("--policy.path is required (a LeRobot checkpoint's pretrained_model folder)")
    if cfg.episodes_per_task < 1:
        raise AdaDemoError(f"--episodes_per_task must be >= 1, got {cfg.episodes_per_task}")
    if cfg.output_dir is None:
        raise AdaDemoError("--output_dir is required")
    check_writable_location(Path(cfg.output_dir), "--output_dir")  # before the episodes run, not after
    cfg.validate_execution()
    suite_config, tasks = suite_to_evaluate(cfg.dataset.root, cfg.suite)
    suite = make_suite(suite_config)
    check_policy(cfg.policy.path, dataset_features(suite))
    # The same weights acting otherwise: a config of its own beside the records, linking the rest.
    policy_path, readout = Path(cfg.policy.path), cfg.policy.readout()
    readout_folder = Path(cfg.output_dir) / "policy_readout"
    if readout:
        check_readout(policy_path, readout, readout_folder)
    executor = make_executor(cfg, suite, ScriptedCollectorConfig(), cfg.eval.batch_size)
    try:
        if readout:
            policy_path = write_readout_policy(policy_path, readout, readout_folder)
        executor.use_policy(str(policy_path))
        records, env_steps, elapsed = evaluate_fixed_set(
            suite, executor, cfg.seed, cfg.episodes_per_task, tasks
        )
    finally:
        executor.close()
    success = success_table(records, tasks)
    print(format_success_table(success))
    write_eval_outputs(
        Path(cfg.output_dir),
        records,
        success,
        {
            "policy_path": str(cfg.policy.path),
            "readout": readout,
            "seed": cfg.seed,
            "episodes_per_task": cfg.episodes_per_task,
            "env_steps": env_steps,
            "wall_seconds": elapsed,
            "suite": suite.config.to_dict(),
        },
    )
    print(
        f"{env_steps} env steps in {elapsed:.1f} s ({env_steps / max(elapsed, 1e-9):.0f} steps/s); "
        f"records: {Path(cfg.output_dir) / 'eval_episodes.parquet'}"
    )
    return success
