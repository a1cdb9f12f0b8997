"""Ctrl-C, SIGTERM and SIGHUP inside a block that must not be cut short (a rollback, a commit): they take effect
when it ends, however often they come and whichever thread the kernel hands them to; the handler that was set
runs then (Python's Ctrl-C, the commands' SIGTERM, the default termination). In a fresh interpreter each, as a
command would meet them."""

import subprocess
import sys

import pytest

SCRIPT = """
import os, signal, sys, threading, time
from adademo_lerobot.core.interrupts import raise_keyboard_interrupt, signals_deferred

sig = getattr(signal, sys.argv[1])
if sys.argv[2] == "command":  # as run_command sets SIGTERM and SIGHUP
    signal.signal(sig, raise_keyboard_interrupt)
elif sys.argv[2] == "python":  # Ctrl-C as in a terminal, even when the suite runs in the background (SIG_IGN)
    signal.signal(sig, signal.default_int_handler)
handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
busy = threading.Event()
threading.Thread(target=busy.wait, daemon=True).start()  # a second thread the kernel may deliver to
finished = False
try:
    with signals_deferred():
        for _ in range(3):  # pressed three times, from another thread
            sender = threading.Thread(target=os.kill, args=(os.getpid(), sig))
            sender.start()
            sender.join()
            time.sleep(0.05)
        finished = True
        print("block done", flush=True)
    print("after the block", flush=True)
except KeyboardInterrupt:
    restored = all(signal.getsignal(s) is h for s, h in handlers.items())
    print(f"interrupted after the block: {finished}, handlers restored: {restored}", flush=True)
    sys.exit(130)
"""


@pytest.mark.parametrize(
    "sig, handler, out, code",
    [
        ("SIGINT", "python", "block done\ninterrupted after the block: True, handlers restored: True", 130),
        ("SIGTERM", "command", "block done\ninterrupted after the block: True, handlers restored: True", 130),
        ("SIGHUP", "command", "block done\ninterrupted after the block: True, handlers restored: True", 130),
        ("SIGTERM", "default", "block done", -15),  # terminated at the block's end, not inside it
    ],
)
def test_signals_inside_a_deferred_block_take_effect_at_its_end(sig, handler, out, code):
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, sig, handler], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == code, proc.stderr[-2000:]
    assert proc.stdout.strip() == out
    assert "Traceback" not in proc.stderr


def test_a_stopped_command_ignores_further_signals_until_the_next_command_starts():
    """Stopping (a first signal, or a person's q/Esc in adademo-record) raises once; signals after it are ignored
    while the command unwinds; the next command in the same process stops on its first signal again."""
    from adademo_lerobot.core.interrupts import command_starts, raise_keyboard_interrupt, stop_command

    command_starts()
    with pytest.raises(KeyboardInterrupt):
        stop_command()  # adademo-record's q/Esc
    raise_keyboard_interrupt(15, None)  # ignored: the command is already stopping
    command_starts()
    with pytest.raises(KeyboardInterrupt):
        raise_keyboard_interrupt(15, None)
    raise_keyboard_interrupt(2, None)
    command_starts()  # this test's process is no command: leave it not stopping
