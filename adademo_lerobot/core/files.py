"""Durable file writes: a file is either its old content or its new content, never half of either."""

from __future__ import annotations

import json
import os
import threading
from contextlib import contextmanager, suppress
from pathlib import Path

# Held while a dataset commit writes or rolls back: a command that must leave at once (os._exit) takes it first,
# so that it never leaves in the middle of a commit.
COMMIT_LOCK = threading.RLock()


def check_writable_location(path: Path, what: str) -> None:
    """`path` may not exist yet, but its nearest existing ancestor must be a writable folder: checked by creating
    (and at once removing) a file there, since permissions alone do not tell (root, read-only mounts, immutable
    folders)."""
    import tempfile

    from adademo_lerobot.core.errors import AdaDemoError

    parent = Path(path)
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise AdaDemoError(
            f"cannot write {what} {path}: {parent} is a file, not a folder; choose another path"
        )
    try:
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as err:
        raise AdaDemoError(
            f"cannot write {what} {path}: {parent} is not a writable folder ({err.strerror or err})"
        ) from None


@contextmanager
def exclusive_use(folder: Path, command: str):
    """Hold an advisory lock on `folder` while `command` writes there: a second command on the same folder is
    refused instead of interleaving its writes with ours (or rolling back our write in progress as a crashed one).
    The kernel releases the lock when the process ends, however it ends."""
    import fcntl

    from adademo_lerobot.core.errors import AdaDemoError

    if not Path(folder).is_dir():  # nothing there yet to protect (the command checks its input itself)
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise AdaDemoError(
                f"{folder} is in use by another running adademo command; wait for it to finish (or stop it), "
                f"then rerun {command}"
            ) from None
        yield
    finally:
        os.close(fd)


def atomic_write_text(path: Path, text: str) -> None:
    """Write to a sibling temporary file, fsync it, then rename it over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:  # a full disk: the old content stays, and no half-written temporary file
        with suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_json(path: Path, data, indent: int | None = 2) -> None:
    atomic_write_text(path, json.dumps(data, indent=indent, sort_keys=indent is not None) + "\n")


def sync_file(path: Path) -> None:
    """fsync a file written without it (what every process wrote to it, not only this one's descriptor)."""
    with open(path, "rb") as f:
        os.fsync(f.fileno())


def append_json_lines(path: Path, entries: list[dict], sync: bool = True) -> None:
    """Append one JSON object per line: once this returns, a kill of the process cannot lose them, and with
    `sync` (fsync) neither can a crash of the machine. A write that fails (a full disk) is cut off again, and a
    line a kill tore is dropped before appending, so that every line after it stays readable."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = "".join(json.dumps(e) + "\n" for e in entries).encode()
    with open(path, "a+b") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(max(0, size - 1))
        if size and f.read(1) != b"\n":  # torn by a kill: keep whole lines (read further back only then)
            f.seek(max(0, size - 65536))
            tail = f.read()
            cut = tail.rfind(b"\n") + 1
            if cut or len(tail) == size:
                size -= len(tail) - cut
                f.truncate(size)
        try:
            f.write(data)
            f.flush()
            if sync:
                os.fsync(f.fileno())
        except BaseException:
            with suppress(OSError):
                f.truncate(size)
            raise


def read_json_lines(path: Path) -> list[dict]:
    """Every complete JSON line; a last line torn by a kill (and anything after it) is ignored."""
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break
    return out
