"""The adademo section of a dataset's card (`adademo-push` puts it in LeRobot's `dataset_description` slot): the
suite, the strategies, a table of the rounds and what the `adademo/*` columns and files mean."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.layout import (
    ADADEMO_DIR,
    COL_ROUND,
    COL_SOURCE,
    CORRECTION_SOURCE,
    LEDGER_FILE,
    SUITE_FILE,
)
from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import load_suite_config, read_episode_metadata
from adademo_lerobot.strategies import StrategyConfig

# Per-task columns in the round table up to this many tasks; beyond it, one row per (round, task) instead.
MAX_TASK_COLUMNS = 8


# How the card describes each source of episodes: round 0's, and every strategy's own description.
SOURCE_DESCRIPTIONS = {
    "initial": "initial collection: expert demonstrations from random initial states (round 0)",
    "correction": "corrections: the expert took over a failed policy rollout and finished the task from there",
    "human": "demonstrations a person teleoperated on the robot (adademo-record)",
    "imported": "episodes recorded elsewhere (no adademo provenance)",
    "policy": "the policy's own episodes, kept by lerobot-rollout's DAgger (not imitated by default)",
}


def source_description(name: str) -> str:
    try:
        return StrategyConfig.get_choice_class(name).description
    except KeyError:
        return SOURCE_DESCRIPTIONS.get(name, "recorded by another tool")


COLUMN_DESCRIPTIONS = {
    "adademo/round": "expansion round that added the episode (0 = initial collection)",
    "adademo/source": "`initial`, the strategy that added it (`adademo`, `budgeted`, `uniform`, `task_only`), "
    "`correction` (the expert or a person took over a failed policy rollout), `policy` (the policy's own, in "
    "LeRobot's DAgger data) or `imported`",
    "adademo/seed": "seed of the episode's initial state (with the suite, reproduces it)",
    "adademo/initial_state": "the initial state itself (float64 list; MetaWorld: the task's random vector)",
    "adademo/collector": "the expert that recorded it",
    "adademo/suite": "the task-suite family",
    "adademo/start_step": "the step it starts at: 0, or a correction's step of the failed rollout it answers",
    "adademo/start_state": "the whole simulator state it starts from (a robot's joint positions): it replays from it",
}


@dataclass
class RoundSummary:
    round: int
    strategies: list[str]
    settings: str  # e.g. "E=10, CAP=50"
    demos: dict[str, int]  # task -> episodes the round added
    evals: dict[str, tuple[int, int]]  # task -> (successes, evaluation episodes), tasks the round evaluated
    total_after: int
    in_ledger: bool


def _settings(records: list[dict]) -> str:
    if not records:
        return ""
    r = records[0]
    values = {
        "E": r.get("target_successes"),
        "CAP": r.get("max_demos_per_task"),
        "N": r.get("demos_per_task"),
        "B": (r.get("extra") or {}).get("budget"),
    }
    return ", ".join(f"{label}={value}" for label, value in values.items() if value is not None)


def summarize_rounds(root: Path, tasks: list[str]) -> list[RoundSummary]:
    """Every round present in the dataset or the ledger, with its demos (from the episodes) and evaluations."""
    eps = read_episode_metadata(root)
    ledger = read_ledger(root)
    rounds = sorted({int(r) for r in eps[COL_ROUND]} | {int(r["round"]) for r in ledger})
    out = []
    for rnd in rounds:
        new = eps[eps[COL_ROUND] == rnd]
        records = [r for r in ledger if r["round"] == rnd]
        strategies = sorted({r["strategy"] for r in records} or set(new[COL_SOURCE]))
        if records and (new[COL_SOURCE] == CORRECTION_SOURCE).any():
            strategies.append(CORRECTION_SOURCE)
        out.append(
            RoundSummary(
                round=rnd,
                strategies=strategies,
                settings=_settings(records),
                demos={t: int((new["task"] == t).sum()) for t in tasks},
                evals={
                    r["task"]: (int(r["successes"]), int(r["eval_episodes"]))
                    for r in records
                    if r.get("eval_episodes")
                },
                total_after=int((eps[COL_ROUND] <= rnd).sum()),
                in_ledger=bool(records),
            )
        )
    return out


def _sr(evaluation: tuple[int, int] | None) -> str:
    if not evaluation:
        return "–"
    successes, episodes = evaluation
    return f"{100 * successes / episodes:.0f}% ({successes}/{episodes})"


def _strategy_cell(s: RoundSummary) -> str:
    name = ", ".join(f"`{x}`" for x in s.strategies)
    if s.settings:
        name += f" ({s.settings})"
    if not s.in_ledger and s.round != 0:
        name += " (no ledger record)"
    return name


def adademo_card_section(root: str | Path, max_task_columns: int = MAX_TASK_COLUMNS) -> str:
    """Markdown for the card's description: suite, strategies, the per-round table, the adademo/* columns."""
    root = Path(root)
    suite = load_suite_config(root)
    eps = read_episode_metadata(root)
    info = json.loads((root / "meta" / "info.json").read_text())
    tasks = [t for t in suite.tasks.split(",") if t]
    tasks += [t for t in dict.fromkeys(eps["task"]) if t not in tasks]
    rounds = summarize_rounds(root, tasks)
    used = sorted({s for r in rounds for s in r.strategies})

    lines = [
        "### AdaDemo",
        "",
        "Grown with **adademo-lerobot**, the method of *AdaDemo: Data-Efficient Demonstration Expansion for "
        "Generalist Robotic Agent*: evaluate the policy, collect expert demonstrations from the initial states "
        "where it fails (more for tasks it solves less often), append them, retrain. It is a standard LeRobot "
        "v3.0 dataset: `LeRobotDataset(repo_id)` loads it.",
        "",
        f"- **Suite:** `{suite.type}` ({suite.obs_type} observations, at most {suite.max_episode_steps} steps per "
        f"episode), {len(tasks)} task(s): {', '.join(f'`{t}`' for t in tasks)}",
        f"- **Episodes:** {len(eps)} ({info.get('total_frames', '?')} frames at {info.get('fps', '?')} fps) from "
        f"{len(rounds)} round(s), round 0 = initial collection",
        "- **Strategies used:**",
        *[f"  - `{s}`: {source_description(s)}" for s in used],
        "",
        "#### Rounds",
        "",
    ]
    if len(tasks) <= max_task_columns:
        rows = [
            [
                s.round,
                _strategy_cell(s),
                *(f"+{s.demos[t]} / {_sr(s.evals.get(t))}" for t in tasks),
                s.total_after,
            ]
            for s in rounds
        ]
        lines += [
            "Per task: demonstrations the round added / the policy's success rate on that round's evaluation "
            "episodes (`–`: the round evaluated no policy on that task).",
            "",
            table(
                ["round", "strategy", *(f"{t}: demos / eval SR" for t in tasks), "episodes after round"],
                rows,
                aligned=False,
                right=(0, len(tasks) + 2),
            ),
        ]
    else:
        rows = []
        for s in rounds:
            total = (sum(v[0] for v in s.evals.values()), sum(v[1] for v in s.evals.values()))
            rows.append(
                [
                    s.round,
                    _strategy_cell(s),
                    f"+{sum(s.demos.values())}",
                    _sr(total if total[1] else None),
                    s.total_after,
                ]
            )
        per_task = [[s.round, t, f"+{s.demos[t]}", _sr(s.evals.get(t))] for s in rounds for t in tasks]
        lines += [
            table(
                ["round", "strategy", "demos added", "eval SR (all tasks)", "episodes after round"],
                rows,
                aligned=False,
                right=(0, 2, 4),
            ),
            "",
            "Per task (`–`: no policy evaluation on that task in that round):",
            "",
            table(["round", "task", "demos added", "eval SR"], per_task, aligned=False, right=(0, 2)),
        ]
    lines += [
        "",
        "#### Per-episode columns",
        "",
        "`meta/episodes` carries these columns besides LeRobot's own:",
        "",
        table(["column", "meaning"], [[f"`{c}`", d] for c, d in COLUMN_DESCRIPTIONS.items()], aligned=False),
        "",
        "#### AdaDemo files",
        "",
        f"- `{SUITE_FILE}`: the suite (type, tasks in one-hot order, observations), enough to rebuild the envs",
        f"- `{LEDGER_FILE}`: one record per round and task (strategy, E, CAP, N, policy, evaluation episodes, "
        "successes, demos added, expert failures, env steps, wall time)",
        f"- `{ADADEMO_DIR}/round-NNN-evaluations.jsonl`: every evaluation outcome of a round (which initial states "
        "the policy failed)",
    ]
    return "\n".join(lines)
