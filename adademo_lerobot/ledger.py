"""The round journal (crash safety) and the round ledger (accounting), both stored with the dataset.

- `meta/adademo/rounds.jsonl`: one record per (round, task) once a round is complete: strategy, E, CAP,
  policy, evaluation episodes and outcomes, demos added, expert failures, whether CAP was hit, env steps
  spent on evaluation and on collection, wall seconds. The paper did not account for evaluation; we do.
- `meta/adademo/journal-round-NNN.jsonl`: append-only, fsync'd log of a round in progress (its settings,
  every evaluation outcome, every expert failure). Rerunning an interrupted round replays it instead of
  re-evaluating, so the round continues exactly where it stopped. Once the ledger is written it is kept as
  `meta/adademo/round-NNN-evaluations.jsonl`: the record of which initial states the policy failed.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from adademo_lerobot.dataset.store import ADADEMO_DIR, atomic_write_text
from adademo_lerobot.errors import AdaDemoError

LEDGER_FILE = f"{ADADEMO_DIR}/rounds.jsonl"


@dataclass
class TaskRoundRecord:
    round: int
    task: str
    strategy: str
    target_successes: int | None
    max_demos_per_task: int | None
    demos_per_task: int | None
    policy_path: str | None
    eval_episodes: int = 0  # episodes the strategy consumed (Algorithm 1's evaluations)
    eval_episodes_run: int = 0  # including a batch's overshoot past the stopping point (real cost)
    successes: int = 0
    failures: int = 0
    demos_added: int = 0
    expert_failures: int = 0
    cap_hit: bool = False
    eval_bound_hit: bool = False
    planned_demos: int | None = None  # task_only: N_k = E/SR_k - E (capped)
    eval_env_steps: int = 0
    collection_env_steps: int = 0
    wall_seconds: float = 0.0
    expert_failed_states: list[dict] = field(default_factory=list)

    @property
    def success_rate(self) -> float | None:
        return self.successes / self.eval_episodes if self.eval_episodes else None


def read_ledger(root: Path) -> list[dict]:
    path = Path(root) / LEDGER_FILE
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def append_ledger(root: Path, records: list[TaskRoundRecord]) -> None:
    """Rewrites the small ledger file atomically, so it never holds half a round."""
    rows = read_ledger(root)
    done_rounds = {r["round"] for r in rows}
    new_rounds = {r.round for r in records}
    if done_rounds & new_rounds:
        raise AdaDemoError(f"round(s) {sorted(done_rounds & new_rounds)} are already in the ledger")
    rows += [asdict(r) for r in records]
    atomic_write_text(Path(root) / LEDGER_FILE, "".join(json.dumps(r) + "\n" for r in rows))


class RoundJournal:
    def __init__(self, root: Path, round_index: int):
        self.path = Path(root) / ADADEMO_DIR / f"journal-round-{round_index:03d}.jsonl"
        self.round_index = round_index

    @staticmethod
    def in_progress(root: Path) -> list[int]:
        return sorted(int(p.stem.split("-")[-1]) for p in (Path(root) / ADADEMO_DIR).glob("journal-round-*.jsonl"))

    def exists(self) -> bool:
        return self.path.exists()

    def entries(self) -> list[dict]:
        if not self.path.exists():
            return []
        out = []
        for line in self.path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                break  # a line torn by a kill: everything before it is intact
        return out

    def append(self, *entries: dict) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            for e in entries:
                f.write(json.dumps(e) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def start(self, settings: dict) -> None:
        """Begin the round, or check that a resumed round uses the same settings."""
        entries = self.entries()
        if not entries:
            self.append({"type": "start", **settings})
            return
        started = {k: v for k, v in entries[0].items() if k != "type"}
        diffs = [k for k in settings if started.get(k) != settings[k]]
        if diffs:
            details = ", ".join(f"{k}: {started.get(k)!r} -> {settings[k]!r}" for k in diffs)
            raise AdaDemoError(
                f"round {self.round_index} was started with other settings ({details}); rerun it with the same "
                f"flags to finish it, or delete {self.path} to discard its evaluations"
            )

    def evaluations(self, task: str) -> dict[int, dict]:
        return {e["seed"]: e for e in self.entries() if e["type"] == "eval" and e["task"] == task}

    def expert_failures(self, task: str) -> dict[int, dict]:
        return {e["seed"]: e for e in self.entries() if e["type"] == "expert_failure" and e["task"] == task}

    def seconds(self, task: str) -> float:
        return sum(e["seconds"] for e in self.entries() if e["type"] == "time" and e["task"] == task)

    @property
    def archive_path(self) -> Path:
        return self.path.with_name(f"round-{self.round_index:03d}-evaluations.jsonl")

    def finish(self) -> None:
        """Keep the round's evaluation records (which states failed) beside the ledger; end the journal."""
        if self.path.exists():
            os.replace(self.path, self.archive_path)


def read_round_evaluations(root: Path, round_index: int) -> list[dict]:
    """Every evaluation outcome and expert failure of a finished round."""
    journal = RoundJournal(root, round_index)
    path = journal.archive_path if journal.archive_path.exists() else journal.path
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
