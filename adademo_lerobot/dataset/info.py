"""A dataset's `meta/info.json` (LeRobot's: features, fps, counts), read with a one-line error when missing or
damaged."""

from __future__ import annotations

import json
from pathlib import Path

from adademo_lerobot.core.errors import AdaDemoError


def read_info(root: str | Path) -> dict:
    path = Path(root) / "meta" / "info.json"
    if not path.exists():
        raise AdaDemoError(f"no LeRobot dataset at {root} (missing meta/info.json)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise AdaDemoError(
            f"{path} is not valid JSON ({err.msg} at line {err.lineno}); the dataset is damaged"
        ) from None
