"""`adademo-expand`: one round of dataset expansion (Algorithm 1, lines 3-17) with any strategy.

Everything the round decides is journaled before it acts (see `ledger.py`), every dataset append is a
transaction (see `dataset/store.py`), so `kill -9` at any moment followed by the same command finishes the
same round: no initial state gets two demonstrations in a round and the ledger matches the dataset.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
from tqdm import tqdm

from adademo_lerobot.collectors.base import make_collector
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.store import COL_ROUND, DemoDataset, load_suite_config, read_episode_metadata
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.evaluation import BatchedEvaluator, load_policy
from adademo_lerobot.ledger import RoundJournal, TaskRoundRecord, append_ledger, read_ledger
from adademo_lerobot.strategies import make_strategy, planned_demos
from adademo_lerobot.strategies.base import RoundContext
from adademo_lerobot.strategies.task_only import plan_state_seeds
from adademo_lerobot.suites.base import make_suite


def validate(cfg) -> None:
    make_strategy(cfg.strategy)
    for flag, value in (("target_successes", cfg.target_successes), ("max_demos_per_task", cfg.max_demos_per_task),
                        ("demos_per_task", cfg.demos_per_task), ("plan_episodes_per_task", cfg.plan_episodes_per_task)):
        if value < 1:
            raise AdaDemoError(f"--{flag} must be >= 1, got {value}")
    if cfg.max_eval_episodes_per_task is not None and cfg.max_eval_episodes_per_task < 1:
        raise AdaDemoError(f"--max_eval_episodes_per_task must be >= 1, got {cfg.max_eval_episodes_per_task}")
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (an adademo dataset made by adademo-collect)")
    if not (Path(cfg.dataset.root) / "meta" / "info.json").exists():
        raise AdaDemoError(f"no LeRobot dataset at {cfg.dataset.root}; create one with adademo-collect")


def next_round(root: Path) -> int:
    """The round in progress (journaled), else one past the last round in the ledger or the dataset."""
    in_progress = RoundJournal.in_progress(root)
    if in_progress:
        return in_progress[0]
    eps = read_episode_metadata(root)
    ledger_rounds = [r["round"] for r in read_ledger(root)]
    last = max([0, *ledger_rounds, *(eps[COL_ROUND].tolist() if len(eps) else [])])
    return last + 1


def format_round_table(records: list[TaskRoundRecord]) -> str:
    lines = [f"{'task':<26} {'eval':>5} {'SR':>6} {'demos':>6} {'expert fail':>11} {'cap':>4} {'eval steps':>10} "
             f"{'collect steps':>13}", "-" * 90]
    for r in records:
        sr = f"{100 * r.success_rate:.0f}%" if r.success_rate is not None else "-"
        lines.append(f"{r.task:<26} {r.eval_episodes:>5} {sr:>6} {r.demos_added:>6} {r.expert_failures:>11} "
                     f"{'yes' if r.cap_hit else '':>4} {r.eval_env_steps:>10} {r.collection_env_steps:>13}")
    lines.append(f"{'total':<26} {sum(r.eval_episodes for r in records):>5} {'':>6} "
                 f"{sum(r.demos_added for r in records):>6} {sum(r.expert_failures for r in records):>11} {'':>4} "
                 f"{sum(r.eval_env_steps for r in records):>10} {sum(r.collection_env_steps for r in records):>13}")
    return "\n".join(lines)


def plan(cfg, suite, evaluator: BatchedEvaluator, round_index: int) -> list[dict]:
    """Evaluate and predict each task's demos without collecting (price a round before paying for it)."""
    rows = []
    for task in tqdm(suite.tasks, desc="planning", unit="task", dynamic_ncols=True):
        outcomes = evaluator.run(task, plan_state_seeds(cfg.seed, round_index, task, cfg.plan_episodes_per_task))
        sr = sum(o.success for o in outcomes) / len(outcomes)
        rows.append({"task": task, "episodes": len(outcomes), "successes": sum(o.success for o in outcomes),
                     "success_rate": sr, "predicted_demos": planned_demos(cfg.target_successes, sr, cfg.max_demos_per_task)})
    print(f"plan for round {round_index} (E={cfg.target_successes}, CAP={cfg.max_demos_per_task}); nothing collected")
    print(f"{'task':<26} {'success':>9} {'SR':>6} {'predicted demos':>16}")
    for r in rows:
        print(f"{r['task']:<26} {r['successes']:>4}/{r['episodes']:<4} {100 * r['success_rate']:>5.0f}% {r['predicted_demos']:>16}")
    print(f"{'total':<26} {'':>9} {'':>6} {sum(r['predicted_demos'] for r in rows):>16}   "
          f"({evaluator.env_steps} evaluation env steps)")
    return rows


def run_expand(cfg) -> list[TaskRoundRecord] | list[dict]:
    validate(cfg)
    root = Path(cfg.dataset.root)
    suite = make_suite(load_suite_config(root))
    read_episode_metadata(root)  # fails clearly on a dataset without adademo columns
    strategy = make_strategy(cfg.strategy)
    needs_policy = strategy.needs_policy or cfg.plan_only
    loaded = None
    if needs_policy:
        if cfg.policy.path is None:
            raise AdaDemoError(f"--strategy={cfg.strategy} evaluates a policy: pass --policy.path=CKPT")
        torch.set_num_threads(cfg.torch_threads)
        loaded = load_policy(cfg.policy.path, cfg.device)
        from adademo_lerobot.train import check_policy_matches_dataset

        check_policy_matches_dataset(loaded.config, dataset_features(suite))
    collector = make_collector(cfg.collector, suite)
    evaluator = BatchedEvaluator(suite, loaded, cfg.eval.batch_size) if loaded else None

    dataset = DemoDataset.open(cfg.dataset.repo_id, root)  # rolls back a write a kill left half-done
    round_index = next_round(root)
    if cfg.plan_only:
        return plan(cfg, suite, evaluator, round_index)

    journal = RoundJournal(root, round_index)
    if journal.exists() and any(r["round"] == round_index for r in read_ledger(root)):
        journal.finish()  # killed after the ledger was written: the round is complete
        print(f"round {round_index} was already complete; run the command again for another round")
        return []
    max_eval = cfg.max_eval_episodes_per_task or 2 * (cfg.target_successes + cfg.max_demos_per_task)
    journal.start({
        "strategy": cfg.strategy, "target_successes": cfg.target_successes,
        "max_demos_per_task": cfg.max_demos_per_task, "demos_per_task": cfg.demos_per_task,
        "plan_episodes_per_task": cfg.plan_episodes_per_task, "max_eval_episodes_per_task": max_eval,
        "seed": cfg.seed, "policy_path": str(Path(cfg.policy.path).resolve()) if needs_policy else None,
    })
    bar = tqdm(suite.tasks, desc=f"round {round_index} ({cfg.strategy})", unit="task", dynamic_ncols=True)

    def progress(task: str, record: TaskRoundRecord) -> None:
        bar.set_postfix(task=task, evals=record.eval_episodes, ok=record.successes, demos=record.demos_added,
                        refresh=True)

    ctx = RoundContext(
        suite, dataset, collector, round_index, cfg.seed, source=cfg.strategy, evaluator=evaluator, journal=journal,
        target_successes=cfg.target_successes, max_demos_per_task=cfg.max_demos_per_task,
        demos_per_task=cfg.demos_per_task, max_eval_episodes_per_task=max_eval,
        plan_episodes_per_task=cfg.plan_episodes_per_task, commit_every=cfg.commit_every,
        policy_path=str(cfg.policy.path) if needs_policy else None, on_progress=progress,
    )
    records = []
    for task in bar:
        started = time.perf_counter()
        record = strategy.expand_task(ctx, task)
        ctx.flush(task, started)
        ctx.evaluation_cost(task, record)
        record.wall_seconds = round(journal.seconds(task), 3)
        records.append(record)
    bar.close()
    check_ledger_matches_dataset(root, round_index, records)
    append_ledger(root, records)
    journal.finish()
    if evaluator:
        evaluator.close()
    print(format_round_table(records))
    print(f"round {round_index}: {sum(r.demos_added for r in records)} new episodes in {root}")
    return records


def check_ledger_matches_dataset(root: Path, round_index: int, records: list[TaskRoundRecord]) -> None:
    eps = read_episode_metadata(root)
    counts = eps[eps[COL_ROUND] == round_index].groupby("task").size()
    for r in records:
        if int(counts.get(r.task, 0)) != r.demos_added:
            raise RuntimeError(f"internal error: round {round_index} {r.task}: ledger {r.demos_added} demos, "
                               f"dataset {int(counts.get(r.task, 0))}")
