"""The console entry points (`adademo-*`): each parses its flags and calls the command's function.

They are programs, not the library: what the process needs is set here, before the command's modules are
imported, and never by a library call: the GL backend MuJoCo will render with (`adademo_lerobot.core.gl`, before
anything imports MuJoCo), and the environment variables below (a user's own setting wins).
"""

import os

from adademo_lerobot.core.gl import prefer_loadable_backend

# SVT-AV1 (LeRobot's default video codec) prints ~25 lines of settings per episode it encodes: its errors only.
os.environ.setdefault("SVT_LOG", "1")
# Ray sends usage statistics when it starts: no network beyond the package registries.
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
prefer_loadable_backend()
