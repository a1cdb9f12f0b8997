"""The errors a command reports in one `error:` line instead of a traceback.

`AdaDemoError` is bad input (exit code 2, nothing written); `MachineError` is the machine failing under a command
that was given good input (a full disk, an I/O error, a lost Ray node; exit code 1): its message says what failed
and that the same command resumes, and the command has already put the dataset back as it found it.
"""


class AdaDemoError(Exception):
    """A problem with the user's input or files, stated with what to do about it."""


class MachineError(AdaDemoError):
    """The machine failed under the command; the message says what failed, where, and that a rerun resumes."""

    # Leave at once, without the interpreter's exit hooks: after a lost Ray cluster, Ray's own hook would wait
    # about a minute for it to come back before the process could end.
    exit_at_once: bool = False


class LostRayClusterError(MachineError):
    exit_at_once = True
