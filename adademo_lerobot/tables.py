"""The one table formatter: GitHub-flavoured markdown, readable in a terminal and in report.md alike."""

from __future__ import annotations

from collections.abc import Sequence

from tabulate import tabulate


def table(headers: Sequence[str], rows: Sequence[Sequence], floatfmt: str = ".1f") -> str:
    return tabulate(
        [list(r) for r in rows],
        headers=list(headers),
        tablefmt="github",
        floatfmt=floatfmt,
        disable_numparse=True,
    )
