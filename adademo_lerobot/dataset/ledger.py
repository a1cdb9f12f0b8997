"""The round journal (crash safety) and the round ledger (accounting), both stored with the dataset.

- `meta/adademo/rounds.jsonl`: one record per (round, task) once a round is complete: strategy, E, CAP,
  policy, evaluation episodes and outcomes, demos added, expert failures, whether CAP was hit, env steps
  spent on evaluation and on collection, wall seconds. The paper did not account for evaluation; we do.
- `meta/adademo/journal-round-NNN.jsonl`: append-only, fsync'd log of a round in progress (its settings,
  every evaluation outcome, every expert failure). Rerunning an interrupted round replays it instead of
  re-evaluating, so the round continues exactly where it stopped. Once the ledger is written it is kept as
  `meta/adademo/round-NNN-evaluations.jsonl`: the record of which initial states the policy failed.

The journal is read once and then kept in memory (appends go to both), so a round's bookkeeping costs O(1) per
evaluation however long the round.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from dataclasses import asdict
from pathlib import Path

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import append_json_lines, atomic_write_text, read_json_lines, sync_file
from adademo_lerobot.dataset.layout import ADADEMO_DIR, LEDGER_FILE


def read_ledger(root: Path) -> list[dict]:
    return read_json_lines(Path(root) / LEDGER_FILE)


def ledger_rounds(root: Path) -> set[int]:
    return {int(r["round"]) for r in read_ledger(root)}


def append_ledger(root: Path, records: list[TaskRoundRecord]) -> None:
    """Rewrites the small ledger file atomically, so it never holds half a round."""
    rows = read_ledger(root)
    done_rounds = {r["round"] for r in rows}
    new_rounds = {r.round for r in records}
    if done_rounds & new_rounds:
        raise AdaDemoError(f"round(s) {sorted(done_rounds & new_rounds)} are already in the ledger")
    rows += [asdict(r) for r in records]
    atomic_write_text(Path(root) / LEDGER_FILE, "".join(json.dumps(r) + "\n" for r in rows))


def setting_changes(name: str, before, after) -> list[str]:
    """`name: before -> after`; for a config (a dict) of one type, each field that changed."""
    configs = isinstance(before, dict) and isinstance(after, dict)
    if not configs or before.get("type") != after.get("type"):
        if configs:
            return [f"{name}.type: {before.get('type')!r} -> {after.get('type')!r}"]
        return [f"{name}: {before!r} -> {after!r}"]
    return [
        f"{name}.{k}: {before.get(k)!r} -> {after.get(k)!r}"
        for k in {**before, **after}
        if before.get(k) != after.get(k)
    ]


class RoundJournal:
    """The journal of one round. Entries: `start` (settings), `eval` (one evaluation outcome), `demo` (a collected
    demonstration's cost), `expert_failure`, `time` (seconds spent on a task), and whatever a strategy records
    for itself (e.g. `plan`)."""

    def __init__(self, root: Path, round_index: int):
        self.path = Path(root) / ADADEMO_DIR / f"journal-round-{round_index:03d}.jsonl"
        self.round_index = round_index
        self._entries: list[dict] | None = None
        self._evals: dict[str, dict[int, dict]] = defaultdict(dict)
        self._expert_failures: dict[str, dict[int, dict]] = defaultdict(dict)
        self._demos: dict[str, dict[int, dict]] = defaultdict(dict)
        self._seconds: dict[str, float] = defaultdict(float)
        self._unsynced = False

    @staticmethod
    def in_progress(root: Path) -> list[int]:
        return sorted(
            int(p.stem.split("-")[-1]) for p in (Path(root) / ADADEMO_DIR).glob("journal-round-*.jsonl")
        )

    def exists(self) -> bool:
        return self.path.exists()

    def _index(self, entry: dict) -> None:
        kind = entry.get("type")
        if kind == "eval":
            self._evals[entry["task"]][entry["seed"]] = entry
        elif kind == "expert_failure":
            self._expert_failures[entry["task"]][entry["seed"]] = entry
        elif kind == "demo":
            self._demos[entry["task"]][entry["seed"]] = entry
        elif kind == "time":
            self._seconds[entry["task"]] += entry["seconds"]

    def entries(self) -> list[dict]:
        if self._entries is None:
            self._entries = read_json_lines(self.path)
            for entry in self._entries:
                self._index(entry)
        return self._entries

    def append(self, *entries: dict, sync: bool = True) -> None:
        """Entries after the others; without `sync` a kill cannot lose them but a machine crash can, until the
        next `sync()` (a simulated round syncs before each dataset commit: what it lost is run again, the same)."""
        self.entries()  # loaded before the first append, so memory and file stay the same
        append_json_lines(self.path, list(entries), sync)
        self._unsynced |= not sync
        for entry in entries:
            self._entries.append(entry)
            self._index(entry)

    def sync(self) -> None:
        """Every entry so far durable (a no-op when they all are)."""
        if self._unsynced and self.path.exists():
            sync_file(self.path)
        self._unsynced = False

    def start(self, settings: dict, field_defaults: dict[str, dict] | None = None) -> None:
        """Begin the round, or check that a resumed round uses the same settings. `field_defaults`: the fields of
        the settings that are configs (takeover) at their defaults, which a round journaled before a field
        existed ran as."""
        entries = self.entries()
        if not entries:
            self.append({"type": "start", **settings})
            return
        started = {k: v for k, v in entries[0].items() if k != "type"}
        for name, defaults in (field_defaults or {}).items():
            if isinstance(started.get(name), dict):
                started[name] = defaults | started[name]  # journaled before the field existed
        diffs = [k for k in {**started, **settings} if started.get(k) != settings.get(k)]
        if diffs:
            details = ", ".join(
                change for k in diffs for change in setting_changes(k, started.get(k), settings.get(k))
            )
            raise AdaDemoError(
                f"round {self.round_index} was started with other settings ({details}); rerun it with the same "
                f"flags to finish it, or delete {self.path} to discard its evaluations"
            )

    def evaluations(self, task: str) -> dict[int, dict]:
        self.entries()
        return self._evals[task]

    def expert_failures(self, task: str) -> dict[int, dict]:
        self.entries()
        return self._expert_failures[task]

    def demos(self, task: str) -> dict[int, dict]:
        """Demonstrations collected this round (their cost), by seed; a demo counts once it is in the dataset."""
        self.entries()
        return self._demos[task]

    def seconds(self, task: str) -> float:
        self.entries()
        return self._seconds[task]

    def of_type(self, kind: str) -> list[dict]:
        return [e for e in self.entries() if e.get("type") == kind]

    @property
    def archive_path(self) -> Path:
        return self.path.with_name(f"round-{self.round_index:03d}-evaluations.jsonl")

    def finish(self) -> None:
        """Keep the round's evaluation records (which states failed) beside the ledger; end the journal."""
        self.sync()
        if self.path.exists():
            os.replace(self.path, self.archive_path)


def read_round_evaluations(root: Path, round_index: int) -> list[dict]:
    """Every evaluation outcome and expert failure of a finished (or running) round."""
    journal = RoundJournal(root, round_index)
    path = journal.archive_path if journal.archive_path.exists() else journal.path
    return read_json_lines(path)
