"""The errors a command reports in one `error:` line instead of a traceback.

`AdaDemoError` is bad input (exit code 2, nothing written); `MachineError` is the machine failing under a command
that was given good input (a full disk, an I/O error, a lost Ray node; exit code 1): its message says what failed
and that the same command resumes, and the command has already put the dataset back as it found it.
"""


class AdaDemoError(Exception):
    """A problem with the user's input or files, stated with what to do about it."""


class RoundAbortedError(Exception):
    """Raised in a task's loop when the round stops (another task's loop failed, or Ctrl-C): that loop ends at its
    next step, or at once when it is waiting for workers (`Executor.stop_waiting`), never inside a commit."""


class MachineError(AdaDemoError):
    """The machine failed under the command; the message says what failed, where, and that a rerun resumes."""

    # Leave at once, without the interpreter's exit hooks: after a lost Ray cluster, Ray's own hook would wait
    # about a minute for it to come back before the process could end.
    exit_at_once: bool = False


class LostRayClusterError(MachineError):
    exit_at_once = True


def machine_cause(err: BaseException) -> tuple[str, str]:
    """What failed, in one line, and what to do first, for an error raised under a command: the cause of a
    `MachineError` (the same command resumes afterwards)."""
    import errno

    if isinstance(err, OSError):
        where = f" ({err.filename})" if err.filename else ""
        cause = f"{err.strerror or ' '.join(str(err).split()) or type(err).__name__}{where}"
    else:  # LeRobot's or ours: say what it was, so that a rerun failing the same way can be reported
        cause = f"{type(err).__name__}: {' '.join(str(err).split())}"
    code = getattr(err, "errno", None)
    if code in (errno.ENOSPC, errno.EDQUOT) or "no space left" in str(err).lower():
        return cause, "free space and "
    if code in (errno.EACCES, errno.EPERM, errno.EROFS):
        return cause, "make the folder writable and "
    return cause, "fix the cause and " if isinstance(err, OSError) else ""
