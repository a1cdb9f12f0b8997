"""The round journal's bookkeeping cost over a 2,000-evaluation round (before and after keeping it in memory).

    python benchmarks/journal_bookkeeping.py [--evaluations 2000] [--label after]

Replays what a round does per evaluation with the installed `adademo_lerobot`: look up the journaled
evaluations of the task (resume), append the outcome (fsync), and for a failure look up the expert failures and
journal one. Run it once with the release before the change (its virtualenv) and once with this one; each run
appends its row to benchmarks/results/journal_bookkeeping.md.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from _common import RESULTS, machine_line


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--evaluations", type=int, default=2000)
    parser.add_argument("--label", default="this release")
    args = parser.parse_args()
    import adademo_lerobot
    from adademo_lerobot.dataset.ledger import RoundJournal

    with tempfile.TemporaryDirectory() as tmp:
        journal = RoundJournal(Path(tmp), 1)
        journal.append({"type": "start", "strategy": "adademo"})
        start = time.perf_counter()
        for k in range(args.evaluations):
            task = ("reach-v3", "push-v3")[k % 2]
            if k not in journal.evaluations(task):
                journal.append({"type": "eval", "task": task, "seed": k, "success": k % 3 == 0, "steps": 120})
            # a failure: the expert is asked about it, and fails on every 5th
            if k % 3 and k not in journal.expert_failures(task) and k % 5 == 0:
                failure = {
                    "type": "expert_failure",
                    "task": task,
                    "seed": k,
                    "attempts": 3,
                    "steps": 600,
                    "initial_state": [0.0] * 6,
                }
                journal.append(failure)
        seconds = time.perf_counter() - start
    row = (
        f"| {args.label} (adademo-lerobot {adademo_lerobot.__version__}) | {args.evaluations} | {seconds:.2f} | "
        f"{1000 * seconds / args.evaluations:.2f} |"
    )
    path = RESULTS / "journal_bookkeeping.md"
    if not path.exists():
        path.write_text(
            "\n".join(
                [
                    "# Round journal bookkeeping: a 2,000-evaluation round",
                    "",
                    "Command: `python benchmarks/journal_bookkeeping.py --label ...` with each release's virtualenv; first "
                    f"run: {machine_line()}.",
                    "Per evaluation: journal lookup, append with fsync; per failure: expert-failure lookup (and an append "
                    "for every 5th). The fsync per append is the same in both; the difference is re-reading the journal.",
                    "",
                    "| release | evaluations | seconds | ms per evaluation |",
                    "| --- | --- | --- | --- |",
                ]
            )
            + "\n"
        )
    with open(path, "a") as f:
        f.write(row + "\n")
    print(row)


if __name__ == "__main__":
    main()
