"""Plugins: installed distributions named `adademo_lerobot_*` that register strategies, suites or experts.

A command imports every such distribution, as the module of that very name, before it reads its flags, so
`--strategy.type=mine` (or a suite or expert) parses like a built-in one and `--help` lists it: the convention
LeRobot follows for its own plugins (`lerobot_robot_*`, `lerobot_env_*`, ...), found the same way
(`importlib.metadata`, which also sees editable installs). A library user imports the plugin as any module.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata
import os

from adademo_lerobot.core.errors import AdaDemoError

PLUGIN_PREFIX = "adademo_lerobot_"


def plugin_names(path: list[str]) -> list[str]:
    """The distributions installed on the import path `path` (`sys.path`) whose names start with
    `adademo_lerobot_` (`-` read as `_`), as module names, sorted (the order they register in). Only their
    metadata folders are read: listing every distribution's metadata would cost a tenth of a second."""
    names = set()
    for entry in path:
        # An entry that is a zip, missing or unreadable holds no plugin here.
        with contextlib.suppress(OSError):
            for item in os.scandir(entry or "."):
                metadata = item.name.endswith((".dist-info", ".egg-info"))
                if metadata and item.name.lower().startswith(PLUGIN_PREFIX):
                    name = importlib.metadata.Distribution.at(item.path).metadata.get("Name") or ""
                    names.add(name.replace("-", "_"))
    return sorted(n for n in names if n.startswith(PLUGIN_PREFIX))


def import_plugins(path: list[str]) -> list[str]:
    """Import every plugin on the import path `path` (`plugin_names`) and return their names; one that fails to
    import is refused in one line that names it, whatever it raised (a plugin of another version, a name
    registered twice)."""
    names = plugin_names(path)
    for name in names:
        try:
            importlib.import_module(name)
        except Exception as err:  # noqa: BLE001  (any failure of someone else's code at import: one line)
            why = " ".join(f"{type(err).__name__}: {err}".split())
            raise AdaDemoError(
                f"the plugin {name} failed to import ({why}): fix it, or uninstall it to run without it"
            ) from err
    return names
