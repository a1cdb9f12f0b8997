"""Ctrl-C, SIGTERM and SIGHUP (a closed terminal): commands stop on any of them (`raise_keyboard_interrupt`); a
loop that can save where it is holds the first one until its current step is done (`HeldInterrupts`), so a rerun
loses no finished work; a rollback or a commit is never cut short (`signals_deferred`)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


_stopping = threading.Event()  # a command's first interrupt was raised (`raise_keyboard_interrupt`)


def command_starts() -> None:
    """A new command runs in this process (`run_command`): it is not stopping, whatever one before it did."""
    _stopping.clear()


def stop_command() -> None:
    """Stop the command as its first Ctrl-C would (a person's request to stop, say): KeyboardInterrupt, and every
    signal after it is ignored while the command rolls back and exits (`raise_keyboard_interrupt`)."""
    _stopping.set()
    raise KeyboardInterrupt


def raise_keyboard_interrupt(signum, frame) -> None:
    """The commands' handler of Ctrl-C, SIGTERM and SIGHUP: stop, once. From then on the command is stopping
    (rolling back what is under way, saying how to resume, leaving); a further signal would only cut that short
    at a random place (a traceback from a clean-up, a garbage-collection callback or the interpreter's shutdown),
    so it is ignored. `kill -9` still ends a command at any moment (its journal and transaction file resume it)."""
    if not _stopping.is_set():
        stop_command()


@contextlib.contextmanager
def signals_deferred():
    """Ctrl-C, SIGTERM and SIGHUP arriving inside the block take effect when it ends, whatever their handler was
    (Python's Ctrl-C, the default termination, a caller's own): a rollback or a commit is never left half done,
    however often Ctrl-C is pressed. Blocking the signals would not do: only the calling thread's mask changes, and
    a signal delivered to any other thread still interrupts this one (Python runs its handlers here). An ignored
    signal stays ignored; outside the main thread (where no handler runs) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[int] = []
    # By a handler that ran while the handlers were being swapped: raised after the block.
    raised: list[BaseException] = []
    previous = {}
    try:
        for sig in SIGNALS:
            handler = signal.getsignal(sig)
            if handler not in (signal.SIG_IGN, None):
                previous[sig] = handler
                raised += _set_handler(sig, lambda signum, frame: arrived.append(signum))
        yield
    finally:
        for sig, handler in previous.items():
            raised += _set_handler(sig, handler)
        # A default termination first (it ends the process); then each other signal once, in the order they came.
        for signum in sorted(dict.fromkeys(arrived), key=lambda s: previous[s] is not signal.SIG_DFL):
            if previous[signum] is signal.SIG_DFL:
                os.kill(os.getpid(), signum)
            elif not raised:
                previous[signum](signum, None)
        if raised:
            raise raised[0]


def _set_handler(sig: int, handler) -> list[BaseException]:
    """`signal.signal(sig, handler)`, done whatever happens: CPython first runs the handlers of signals that are
    pending, and one may raise (a Ctrl-C just restored); that error is returned, for the caller to raise once every
    handler is back."""
    raised = []
    while True:
        try:
            signal.signal(sig, handler)
            return raised
        except BaseException as err:  # noqa: BLE001  (KeyboardInterrupt: raised by the caller afterwards)
            raised.append(err)


class HeldInterrupts:
    """Inside `with HeldInterrupts() as held:`, the first Ctrl-C or SIGTERM sets `held.requested` instead of
    raising KeyboardInterrupt, for the loop to save its state and stop at its next step; a second one raises at
    once; `stop()` then raises what the first would have. Only signals that would have raised KeyboardInterrupt
    anyway are held (Python's Ctrl-C handler, the commands' handler): an ignored signal, the default SIGTERM or a
    caller's own handler is left alone, and outside the main thread (or with `enabled=False`) nothing changes."""

    def __init__(self, enabled: bool = True) -> None:
        self.requested = False
        self.enabled = enabled
        self._previous: dict[int, object] = {}
        self._held: tuple[int, object] | None = None  # the signal held and the handler it would have run

    def _hold(self, signum, frame) -> None:
        if self.requested:  # a second one: what it would have done, at once
            self._previous[signum](signum, frame)
            return
        self.requested, self._held = True, (signum, self._previous[signum])

    def stop(self) -> None:
        """What the held signal would have done (the loop has saved its state): KeyboardInterrupt."""
        signum, handler = self._held
        handler(signum, None)
        raise KeyboardInterrupt  # the handler's, unless the command was already stopping

    def __enter__(self) -> HeldInterrupts:
        if self.enabled and threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                handler = signal.getsignal(sig)
                if handler in (signal.default_int_handler, raise_keyboard_interrupt):
                    self._previous[sig] = handler
                    signal.signal(sig, self._hold)
        return self

    def __exit__(self, *exc) -> None:
        # Every handler back even if a pending second signal raises on the way (`_set_handler`), then that error.
        raised = [err for sig, handler in self._previous.items() for err in _set_handler(sig, handler)]
        self._previous.clear()
        if raised:
            raise raised[0]


def detach_from_group_signals(*_) -> None:
    """A DataLoader worker's `worker_init_fn`: a signal sent to the command's process group (a terminal's Ctrl-C
    or SIGHUP, `kill -TERM -PGID`, a service manager's stop) would reach the loader's workers too, and a worker that
    quits on it makes torch fail the held training ("DataLoader worker ... killed by signal") before it saves its
    step. So the worker leaves the group, and ignores Ctrl-C and SIGHUP: the main process stops it when it stops,
    and it exits by itself within seconds if the main process dies (torch's watchdog). A SIGTERM sent to the worker
    itself still ends it: torch's last resort for a stuck worker."""
    with contextlib.suppress(OSError):  # (EPERM, say) a training never fails over it
        os.setpgid(0, 0)
    for sig in (signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
