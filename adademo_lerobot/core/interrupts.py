"""Ctrl-C and SIGTERM: commands stop on either (`raise_keyboard_interrupt`); a loop that can save where it is holds
the first one until its current step is done (`HeldInterrupts`), so a rerun loses no finished work."""

from __future__ import annotations

import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def raise_keyboard_interrupt(signum, frame) -> None:
    """The commands' SIGTERM handler: stop as Ctrl-C does."""
    raise KeyboardInterrupt


class HeldInterrupts:
    """Inside `with HeldInterrupts() as held:`, the first Ctrl-C or SIGTERM sets `held.requested` instead of
    raising KeyboardInterrupt, for the loop to save its state and stop at its next step; a second one raises at
    once. Only signals that would have raised KeyboardInterrupt anyway are held (Python's Ctrl-C handler, the
    commands' SIGTERM handler): an ignored signal, the default SIGTERM or a caller's own handler is left alone,
    and outside the main thread (or with `enabled=False`) nothing changes."""

    def __init__(self, enabled: bool = True) -> None:
        self.requested = False
        self.enabled = enabled
        self._previous: dict[int, object] = {}

    def _hold(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> HeldInterrupts:
        if self.enabled and threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                handler = signal.getsignal(sig)
                if handler in (signal.default_int_handler, raise_keyboard_interrupt):
                    self._previous[sig] = handler
                    signal.signal(sig, self._hold)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()


def ignore_interrupts(*_) -> None:
    """A DataLoader worker's `worker_init_fn`: a terminal's Ctrl-C (or a SIGTERM to the process group) reaches the
    loader's workers too, and a worker that quits on it leaves a held training waiting for a batch that never
    comes; the main process ends the workers itself when it stops."""
    for sig in SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
