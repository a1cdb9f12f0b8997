"""AdaDemo for LeRobot: grow imitation-learning datasets where the policy fails.

The paper's Algorithm 1 lives in :mod:`adademo_lerobot.algorithm`; suites, experts, strategies and samplers are
small classes behind the protocols in their folders.
"""

import os as _os

__version__ = "0.1.0"


def choose_gl_backend() -> None:
    """EGL needs a GPU; without one MuJoCo renders with OSMesa (apt-get install libosmesa6).

    Must run before MuJoCo is imported (it reads MUJOCO_GL once). An explicit MUJOCO_GL always wins.
    """
    if "MUJOCO_GL" not in _os.environ:
        gpu = _os.path.exists("/dev/nvidia0") or _os.path.exists("/dev/dri/renderD128")
        backend = "egl" if gpu else "osmesa"
        _os.environ["MUJOCO_GL"] = backend
        _os.environ.setdefault("PYOPENGL_PLATFORM", backend)


choose_gl_backend()
