"""One exception type for bad user input: the CLI prints its message on one line and exits with code 2."""


class AdaDemoError(Exception):
    """A problem with the user's input or files, stated with what to do about it."""
