"""The one way we override a library attribute: for the length of a `with` block, then restored."""

from __future__ import annotations

import contextlib
from typing import Any

_ABSENT = object()


@contextlib.contextmanager
def temporarily_set(obj: Any, name: str, value: Any):
    """Set `obj.name = value` inside the block; afterwards put back what `obj` itself held (or remove the
    attribute again, so an instance falls back to its class's method)."""
    saved = vars(obj).get(name, _ABSENT) if hasattr(obj, "__dict__") else getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        if saved is _ABSENT:
            delattr(obj, name)
        else:
            setattr(obj, name, saved)
