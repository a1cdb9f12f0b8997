"""A machine without a usable OpenGL library: importing the package and every command works, and asking for
camera images fails with one line naming the package to install, before anything is written.

The missing libraries are simulated for real: the command runs in a private mount namespace where every
libOSMesa and libEGL file is replaced by /dev/null, so both dlopen() and MuJoCo's own loading fail exactly as
on a machine without them (`unshare`, as root; skipped elsewhere, but CI, which runs as root, must run it).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import BIN


def gl_library_files() -> list[str]:
    listing = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    paths = {
        line.split("=>")[-1].strip()
        for line in listing.splitlines()
        if "libOSMesa.so" in line or "libEGL" in line
    }
    return sorted({os.path.realpath(p) for p in paths if os.path.exists(p)})


def without_gl(*command: str, env: dict | None = None) -> subprocess.CompletedProcess:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        if os.environ.get("CI") == "true":
            pytest.fail("CI must run the no-OpenGL test: it needs root and unshare to hide the libraries")
        pytest.skip("hiding the OpenGL libraries needs root and unshare")
    mounts = " && ".join(f"mount --bind /dev/null {p}" for p in gl_library_files()) or "true"
    script = f'{mounts} && exec "$@"'
    return subprocess.run(
        ["unshare", "-m", "sh", "-c", script, "sh", *command],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
    )


def test_without_opengl_the_package_imports_and_pixels_fail_with_one_line(tmp_path):
    probe = (
        "import adademo_lerobot.commands, adademo_lerobot.core.gl as gl, mujoco; "
        "print('osmesa', gl.library_loads('OSMesa'), 'egl', gl.library_loads('EGL'))"
    )
    # Even an explicit MUJOCO_GL=osmesa, which makes `import mujoco` itself fail without libOSMesa, imports in a
    # command (the entry points pick a backend that loads before anything imports MuJoCo).
    proc = without_gl(sys.executable, "-c", probe, env={"MUJOCO_GL": "osmesa"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "osmesa False egl False" in proc.stdout  # the libraries really are gone in there

    root = tmp_path / "pix"
    proc = without_gl(
        str(BIN / "adademo-collect"),
        "--suite.tasks=reach-v3",
        "--suite.obs_type=pixels_state",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/pix",
        f"--dataset.root={root}",
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert (
        lines[-1].startswith("error: camera images need OpenGL rendering")
        and "apt-get install libosmesa6" in lines[-1]
    )
    assert "Traceback" not in proc.stderr
    assert not root.exists() and not any(Path(tmp_path).iterdir())

    # State observations need no OpenGL at all.
    proc = without_gl(
        str(BIN / "adademo-collect"),
        "--suite.tasks=reach-v3",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/state",
        f"--dataset.root={tmp_path / 'state'}",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "state" / "meta" / "info.json").exists()
