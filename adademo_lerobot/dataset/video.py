"""The video decoder LeRobot should use, chosen quietly, and a quiet video encoder.

LeRobot's own default (`get_safe_default_video_backend`) logs a long traceback whenever torchcodec is installed
but cannot load (no system FFmpeg, as on a fresh Debian machine) and then falls back to PyAV. We make the same
choice once, without the noise, and pass it to every dataset we open or create.
"""

from __future__ import annotations

import functools


@functools.cache
def video_backend() -> str:
    try:
        import torchcodec  # noqa: F401  (needs FFmpeg's shared libraries)
    except (ImportError, OSError, RuntimeError):
        return "pyav"
    return "torchcodec"
