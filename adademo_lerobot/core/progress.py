"""Progress bars that follow a loop (a round's demonstrations, training steps) without costing it."""

from __future__ import annotations

import time

REDRAW_S = 0.1  # tqdm's own pace for `update` (its default `mininterval`)


def show(bar, **postfix) -> None:
    """Set a tqdm bar's postfix (`key=value, ...`, as `set_postfix` writes it), redrawing it at most every
    REDRAW_S: `set_postfix` with a redraw per demonstration was ~0.14 ms of the driver's CPU each, a tenth of what a
    Ray round's driver spends per demonstration (benchmarks/results/driver_cost.md)."""
    bar.postfix = ", ".join(f"{key}={value}" for key, value in postfix.items())
    now = time.monotonic()
    if now - getattr(bar, "_adademo_drawn", 0.0) >= REDRAW_S:
        bar._adademo_drawn = now
        bar.refresh()
