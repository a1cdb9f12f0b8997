"""What `adademo-report` reads of a run: success and demonstrations per round and task, the ledger, and what each
expansion round cost (`COSTS`, the cost model of `core/costs.py` per ledger row)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

# What a ledger row (a task in a round) cost: costs.py's model (`high`: the upper bound, where not exact).
COSTS = [
    "demonstrations",
    "expert frames",
    "expert episodes",
    "expert episodes high",
    "rollouts",
    "evaluation steps",
]


@dataclass
class RunResults:
    name: str
    label: str
    tasks: list[str]
    success: pd.DataFrame  # index task (+ "average"), columns round -> success rate
    demos: pd.DataFrame  # index task, columns round -> cumulative demos after that round
    ledger: pd.DataFrame
    started_from: str = ""  # where a run that began from the user's dataset/checkpoint started
    run_dir: Path | None = None
    dataset_root: Path | None = None
    base_round: int = 0
    costs: pd.DataFrame | None = None  # per ledger row (round, task): COSTS

    def added_cost(self, per_task: bool = True) -> pd.DataFrame:
        """Per round (rows, from 0), what the expansion rounds added up to then, per task on average (or in
        all); episodes = expert episodes + rollouts, at the bounds of expert episodes where not exact."""
        rounds = list(self.success.columns)
        out = pd.DataFrame(0.0, index=rounds, columns=COSTS)
        if self.costs is not None and len(self.costs):
            per_round = self.costs.groupby("round")[COSTS].sum() / (len(self.tasks) if per_task else 1)
            out = per_round.reindex(rounds, fill_value=0.0).cumsum()
        out["episodes"] = out["expert episodes"] + out["rollouts"]
        out["episodes high"] = out["expert episodes high"] + out["rollouts"]
        return out


def describe_start(begun: dict) -> str:
    if not begun:
        return ""
    dataset, policy = begun["origin"]["dataset"], begun["origin"]["policy"]
    at = f" at {dataset['commit'][:8]}" if dataset.get("commit") else f" ({dataset['root']})"
    text = f"Started from dataset {dataset['repo_id']}{at}, rounds 0..{begun['base_round']} of it"
    if policy:
        at = f" at {policy['commit'][:8]}" if policy.get("commit") else ""
        text += f", and checkpoint {policy['path']}{at} (round 0 below)"
    return text + "."
