"""The one table formatter: GitHub-flavoured markdown, aligned for a terminal or compact for a document."""

from __future__ import annotations

from collections.abc import Sequence


def table(
    headers: Sequence[str], rows: Sequence[Sequence], aligned: bool = True, right: Sequence[int] = ()
) -> str:
    """Markdown table. `aligned`: pad columns to equal width (terminals); else one space around each cell
    (report.md, dataset cards). `right`: indices of columns aligned right in the markdown."""
    cells = [[str(c) for c in headers]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))] if aligned else [0] * len(headers)
    rule = [("-" * max(w - 1, 2) + ":") if i in right else "-" * max(w, 3) for i, w in enumerate(widths)]

    def line(values: Sequence[str]) -> str:
        return "| " + " | ".join(v.ljust(w) for v, w in zip(values, widths, strict=True)) + " |"

    return "\n".join([line(cells[0]), line(rule), *(line(r) for r in cells[1:])])
