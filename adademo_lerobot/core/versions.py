"""The Python and LeRobot releases this package supports, checked at import with a message that says what to do.

pip enforces the same ranges at install (`requires-python`, the `lerobot` requirement); this catches an
environment changed afterwards (a downgrade, an install with --no-deps) before a deep traceback from LeRobot.
"""

from __future__ import annotations

import sys
from importlib import metadata

PYTHON_MIN = (3, 12)
LEROBOT_MIN = (0, 6, 1)
LEROBOT_BELOW = (0, 6, 3)  # 0.6.2: LeRobot main as checked (pyproject.toml)


class UnsupportedEnvironmentError(ImportError):
    """Python or LeRobot outside the supported range."""


def check_supported_versions() -> None:
    fix = "install it into a fresh virtualenv as README says (`bash setup.sh quickstart`)"
    if sys.version_info[:2] < PYTHON_MIN:
        raise UnsupportedEnvironmentError(
            f"adademo-lerobot needs Python >= {'.'.join(map(str, PYTHON_MIN))} (LeRobot 0.6 does); this is Python "
            f"{sys.version.split()[0]}: {fix}"
        )
    try:
        found = metadata.version("lerobot")
    except metadata.PackageNotFoundError:
        raise UnsupportedEnvironmentError(
            f"adademo-lerobot needs LeRobot, which is not installed: {fix}"
        ) from None
    from packaging.version import InvalidVersion, Version

    try:
        release = Version(found).release
    except InvalidVersion:
        release = ()
    if not LEROBOT_MIN <= release < LEROBOT_BELOW:
        raise UnsupportedEnvironmentError(
            f"adademo-lerobot needs LeRobot >= {'.'.join(map(str, LEROBOT_MIN))}, < "
            f"{'.'.join(map(str, LEROBOT_BELOW))}; this environment has lerobot {found}: "
            f"`pip install 'lerobot[dataset,training,metaworld]>=0.6.1,<0.6.3'`, or {fix}"
        )
