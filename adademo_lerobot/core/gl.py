"""Which OpenGL backend MuJoCo renders with, chosen only from what this machine can actually load.

MuJoCo reads `MUJOCO_GL` once, when `mujoco` is first imported, and imports that backend's bindings then: with
`MUJOCO_GL=osmesa` and no libOSMesa, `import mujoco` itself fails. So `prefer_loadable_backend()` (run by every
command and by LeRobot's import of our plugins, before anything imports MuJoCo) sets `MUJOCO_GL` only to a backend
whose library loads:
EGL on a GPU machine, else OSMesa, else EGL on Mesa's software renderer, else nothing (MuJoCo's default imports
everywhere). State observations never render. Rendering is checked when it is asked for
(`check_rendering_works`) by rendering one tiny frame, so `--suite.obs_type=pixels_state` on a machine that
cannot render fails with one clear line before anything is written.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

from adademo_lerobot.core.errors import AdaDemoError

OSMESA_PACKAGE = "libosmesa6"  # Debian/Ubuntu package with libOSMesa
BACKEND_LIBRARIES = {"osmesa": "OSMesa", "egl": "EGL"}

# A MUJOCO_GL the user set whose library does not load: removed so MuJoCo imports, named in the render error.
_unloadable_request: str | None = None


def library_loads(name: str) -> bool:
    """True if the shared library `name` (e.g. "OSMesa") is found and dlopen() accepts it."""
    path = ctypes.util.find_library(name)
    if path is None:
        return False
    try:
        ctypes.CDLL(path)
    except OSError:
        return False
    return True


def has_gpu_device() -> bool:
    return os.path.exists("/dev/nvidia0") or os.path.exists("/dev/dri/renderD128")


def prefer_loadable_backend() -> str | None:
    """Set MUJOCO_GL (and PYOPENGL_PLATFORM) to a backend whose library loads; returns it, or None when left to
    MuJoCo's default. An explicit MUJOCO_GL wins when its library loads."""
    global _unloadable_request
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested:
        library = BACKEND_LIBRARIES.get(requested)
        if library is None or library_loads(library):
            return requested
        _unloadable_request = requested  # e.g. MUJOCO_GL=osmesa without libOSMesa: `import mujoco` would fail
        del os.environ["MUJOCO_GL"]
        if os.environ.get("PYOPENGL_PLATFORM", "").lower() == requested:
            del os.environ["PYOPENGL_PLATFORM"]
    if has_gpu_device() and library_loads("EGL"):
        backend = "egl"
    elif library_loads("OSMesa"):
        backend = "osmesa"
    elif library_loads("EGL"):
        backend = "egl"  # Mesa's software renderer (llvmpipe) on a machine without a GPU
    else:
        return None
    os.environ["MUJOCO_GL"] = backend
    os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


_rendering_checked = False


def check_rendering_works() -> None:
    """Render one 16x16 frame with MuJoCo's backend; a clear AdaDemoError if that is impossible here."""
    global _rendering_checked
    if _rendering_checked:
        return
    backend = os.environ.get("MUJOCO_GL") or "glfw (MuJoCo's default)"
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>")
        renderer = mujoco.Renderer(model, 16, 16)
        try:
            renderer.update_scene(mujoco.MjData(model))
            renderer.render()
        finally:
            renderer.close()
    except Exception as err:  # noqa: BLE001  (each backend fails with its own exception type)
        detail = " ".join(str(err).split())[:100] or type(err).__name__
        unusable = f"MUJOCO_GL={_unloadable_request} cannot load its library; " if _unloadable_request else ""
        raise AdaDemoError(
            f"camera images need OpenGL rendering, which fails here ({unusable}backend {backend}: {detail}); "
            f"install OSMesa for CPU rendering (`apt-get install {OSMESA_PACKAGE}`), or use a GPU machine with "
            "MUJOCO_GL=egl, or --suite.obs_type=state"
        ) from None
    _rendering_checked = True
