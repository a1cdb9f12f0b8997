"""adademo-report's cost sections: what the expansion rounds cost per round and task, what a person at a
robot pays (expert episodes and rollouts, each a scene reset: the model is `costs.py`) and the break-even
rollout cost against a Uniform run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from adademo_lerobot.core import costs
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.interventions import intervention_flags, segments
from adademo_lerobot.dataset.layout import COL_ROUND, COL_SOURCE, CORRECTION_SOURCE, POLICY_SOURCE
from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.loop.run_results import COSTS, RunResults


def pct(x: float) -> str:
    """A rate as whole percent ('-' where unknown)."""
    return "-" if pd.isna(x) else f"{100 * x:.0f}"


def cost_rows(rows: list[dict], settings: dict, kept: pd.Series) -> pd.DataFrame:
    """Per ledger row, COSTS; `kept`: the frames of the demonstrations kept, by (task, dataset round), for
    rows from before the ledger recorded them."""
    takeover, limit = settings.get("demo_start") == "takeover", settings["suite"].get("max_episode_steps")
    out = []
    for r in rows:
        low, high = costs.expert_episodes(r, limit, takeover, int(kept.get((r["task"], r["round"]), 0)))
        spent = [
            r["demos_added"],
            r["collection_env_steps"],
            low,
            high,
            costs.rollouts(r),
            r["eval_env_steps"],
        ]
        out.append({"round": r["round"], "task": r["task"], **dict(zip(COSTS, spent, strict=True))})
    return pd.DataFrame(out, columns=["round", "task", *COSTS])


def cost_lines(run: RunResults, ledger: pd.DataFrame) -> list[str]:
    """Per round and task, what the round cost: demos (of which corrections), expert frames, evaluation."""
    rows = [
        [
            r["round"],
            r["task"],
            r["demos_added"],
            int(r["corrections"]),
            r["collection_env_steps"],
            int(r["demo_frames"]),
            r.get("eval_episodes_run", r["eval_episodes"]),
            r["eval_env_steps"],
        ]
        for _, r in ledger.iterrows()
    ]
    return [
        "",
        "Cost per round and task (expert frames: env steps under the expert's control, failed attempts "
        "included; demo frames: the frames kept; evaluation: every policy episode the round ran):",
        "",
        table(
            [
                "round",
                "task",
                "demos",
                "corrections",
                "expert frames",
                "demo frames",
                "eval episodes",
                "eval steps",
            ],
            rows,
            aligned=False,
        ),
        "",
        *cost_table(run),
    ]


def _span(added: pd.DataFrame, column: str, r) -> str:
    low, high = added.loc[r, column], added.loc[r, f"{column} high"]
    return f"{low:.0f}" if round(low) == round(high) else f"{low:.0f}-{high:.0f}"


def cost_table(run: RunResults) -> list[str]:
    """What the expansion rounds added up to each round, all tasks: what a person at a robot pays."""
    added = run.added_cost(per_task=False)
    rows = [
        [
            r,
            *(f"{added.loc[r, c]:.0f}" for c in ("demonstrations", "expert frames")),
            _span(added, "expert episodes", r),
            f"{added.loc[r, 'rollouts']:.0f}",
            _span(added, "episodes", r),
            f"{added.loc[r, 'evaluation steps']:.0f}",
            pct(run.success.loc["average", r]),
        ]
        for r in added.index
    ]
    headers = [
        "demonstrations",
        "expert frames",
        "expert episodes",
        "rollouts",
        "episodes",
        "evaluation steps",
    ]
    return [
        f"Added by the expansion rounds up to each round, all {len(run.tasks)} tasks (on a robot each "
        "episode is a scene reset: an expert episode is a demonstration or a failed expert attempt; a "
        "correction from the point of failure is part of its rollout; rollouts: the rounds' policy episodes; "
        "the fixed evaluation set is not counted), and the average success:",
        "",
        table(["after round", *headers, "avg SR %"], rows, aligned=False),
    ]


def break_even_summary(run: RunResults, uniform: RunResults | None) -> list[str]:
    """c* in plain words against a Uniform run, or how to get it."""
    if uniform is None:
        return [
            "Break-even rollout cost (when adaptive collection pays off against Uniform): add "
            "`--compare_to=<a Uniform run on the same tasks>`."
        ]

    def curve(r: RunResults) -> dict:
        added = r.added_cost(per_task=False)
        return {
            "success": list(r.success.loc["average", added.index]),
            "expert": list(added["expert episodes"]),
            "expert_high": list(added["expert episodes high"]),
            "rollouts": list(added["rollouts"]),
        }

    return costs.break_even_lines(curve(run), curve(uniform))


PERSON_COLUMNS = [
    "episodes",
    "demonstrations",
    "corrections",
    "person frames",
    "person seconds",
    "policy frames",
    "policy seconds",
]


def person_work(root: str | Path) -> pd.DataFrame:
    """Per dataset round and task, what a person recorded in the dataset at `root`: demonstrations, corrections
    (each segment a person drove inside a policy episode: LeRobot's DAgger `intervention` flags), the frames
    and recorded seconds the person drove, and the policy's own frames kept beside them. Without the flags every
    episode but the policy's own is the person's (or the expert's) throughout."""
    root = Path(root)
    eps = read_episode_metadata(root)
    fps = float(read_info(root)["fps"])
    if not len(eps):
        return pd.DataFrame(columns=["round", "task", *PERSON_COLUMNS])
    flags = intervention_flags(root)
    if flags is None:  # the whole of every episode but the policy's own
        flags = np.zeros(int(eps["dataset_to_index"].max()), dtype=bool)
        for _, ep in eps[eps[COL_SOURCE] != POLICY_SOURCE].iterrows():
            flags[int(ep["dataset_from_index"]) : int(ep["dataset_to_index"])] = True
    units = segments(flags, eps)
    units["frames"] = units["dataset_to_index"] - units["dataset_from_index"]
    units = units.join(eps[[COL_ROUND, COL_SOURCE]], on="episode_index")
    rows = []
    for (r, task), g in units.groupby([COL_ROUND, "task"], sort=True):
        person, policy = g[g.person], g[~g.person]
        episodes = g.drop_duplicates("episode_index")
        rows.append(
            {
                "round": int(r),
                "task": task,
                "episodes": len(episodes),
                "demonstrations": int((~episodes[COL_SOURCE].isin([CORRECTION_SOURCE, POLICY_SOURCE])).sum()),
                "corrections": int((person[COL_SOURCE] == CORRECTION_SOURCE).sum()),
                "person frames": int(person.frames.sum()),
                "person seconds": round(float(person.frames.sum()) / fps, 1),
                "policy frames": int(policy.frames.sum()),
                "policy seconds": round(float(policy.frames.sum()) / fps, 1),
            }
        )
    return pd.DataFrame(rows, columns=["round", "task", *PERSON_COLUMNS])


def person_lines(root: str | Path) -> list[str]:
    """The person's work in a dataset (`person_work`), per round and task, with the time at the robot each
    adademo-record round's ledger counted (policy episodes and demonstrations, scene resets not included)."""
    work = person_work(root)
    at_robot = {
        (r["round"], r["task"]): r["extra"]["person_seconds"]
        for r in read_ledger(Path(root))
        if "person_seconds" in r.get("extra", {})
    }
    rows = []
    for _, w in work.iterrows():
        spent = at_robot.get((w["round"], w["task"]))
        minutes = "-" if spent is None else f"{sum(spent.values()) / 60:.1f}"
        rows.append([int(w["round"]), w["task"], *(w[c] for c in PERSON_COLUMNS), minutes])
    return [
        f"The person's work in {root}, per dataset round and task (corrections: the segments a person drove inside "
        "a policy episode, from LeRobot's `intervention` flags where the dataset has them; person and policy "
        "frames and their recorded seconds; minutes at the robot: what an adademo-record round's ledger counted):",
        "",
        table(["round", "task", *PERSON_COLUMNS, "minutes at the robot"], rows, aligned=False),
    ]
