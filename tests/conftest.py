"""Shared fixtures: real MetaWorld simulation, real LeRobot datasets written by our own commands."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")
# The tests render in this process as a command would: the GL backend before anything imports MuJoCo.
from adademo_lerobot.core.gl import prefer_loadable_backend  # noqa: E402

prefer_loadable_backend()
# LeRobot's Robot and Teleoperator make a calibration folder under this on creation: not in the user's home.
# Removed when the session ends (every pytest process, xdist workers included, makes its own).
_CALIBRATION_DIR = None
if "HF_LEROBOT_CALIBRATION" not in os.environ:
    _CALIBRATION_DIR = tempfile.mkdtemp(prefix="adademo-tests-calibration-")
    os.environ["HF_LEROBOT_CALIBRATION"] = _CALIBRATION_DIR
BIN = Path(sys.executable).parent
BENCHMARKS = Path(__file__).parents[1] / "benchmarks"


def load_benchmark(name: str):
    """A script of benchmarks/ as a module, loaded afresh: registered in sys.modules (its dataclasses resolve their
    annotations there, and the scripts that import it find it), with benchmarks/ last on sys.path (the scripts
    import _common; last, so it shadows nothing)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.append(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def rendering_works() -> bool:
    """Whether this machine renders camera images (checked once, in a child process, as a command would)."""
    global _RENDERING
    if _RENDERING is None:
        probe = "from adademo_lerobot.core.gl import check_rendering_works; check_rendering_works()"
        _RENDERING = (
            subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=120).returncode == 0
        )
    return _RENDERING


_RENDERING: bool | None = None
# Tests of camera images. Without working rendering they are skipped on a developer's machine, but they fail in
# CI (CI=true), which is meant to run them: setup.sh installs libosmesa6 there.
requires_rendering = pytest.mark.requires_rendering


def pytest_runtest_setup(item):
    if item.get_closest_marker("requires_rendering") and not rendering_works():
        message = "camera images do not render on this machine (apt-get install libosmesa6)"
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI must run the rendering tests: {message}")
        pytest.skip(message)


class CommandServer:
    """tests/command_server.py: console scripts run in forks of a process that has imported torch and LeRobot."""

    # Read when a library is imported, which the server did at its start: a command whose environment differs
    # in one of these runs as a plain subprocess instead.
    IMPORT_TIME = (
        "HF_",
        "HUGGINGFACE",
        "MUJOCO_GL",
        "PYOPENGL",
        "OMP_",
        "MKL_",
        "TORCH",
        "LEROBOT",
        "ADADEMO_TESTS",
        "PYTHONPATH",  # the import path: set when the interpreter starts
    )

    def __init__(self):
        self.env = dict(os.environ)
        server = str(Path(__file__).with_name("command_server.py"))
        # Its own process group: a test that gives up on a command (pytest-timeout) ends the server and the
        # command together (`abandon`).
        self.proc = subprocess.Popen(
            [sys.executable, server],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        assert "ready" in json.loads(self.proc.stdout.readline())
        self.requests = 0

    # Set by importing LeRobot's env configs in the test process; only a cache folder, which a command may share.
    HARMLESS = ("TORCHINDUCTOR_CACHE_DIR",)

    def can_run(self) -> bool:
        changed = {k for k in set(os.environ) | set(self.env) if os.environ.get(k) != self.env.get(k)}
        return not any(k.startswith(self.IMPORT_TIME) and k not in self.HARMLESS for k in changed)

    def run(self, command: str, args: list[str], timeout: int) -> subprocess.CompletedProcess:
        self.requests += 1
        request = {
            "id": self.requests,
            "command": command,
            "args": list(args),
            "cwd": os.getcwd(),
            "env": dict(os.environ),
            "timeout": timeout,
        }
        try:
            self.proc.stdin.write(json.dumps(request) + "\n")
            self.proc.stdin.flush()
            reply = json.loads(self.proc.stdout.readline())
        except BaseException:
            # Left waiting (a test's timeout, Ctrl-C): the reply would come later and be read as the next
            # command's, so every later test would get its predecessor's output. End this server; the next
            # command starts a new one.
            self.abandon()
            raise
        assert reply["id"] == request["id"], (reply, request)
        outputs = []
        for key in ("stdout", "stderr"):
            path = Path(reply[key])
            outputs.append(path.read_text(errors="replace"))
            path.unlink()
        return subprocess.CompletedProcess([command, *args], reply["returncode"], *outputs)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)

    def abandon(self) -> None:
        """Kill the server and the command it runs (one process group), and forget it."""
        global _SERVER
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=60)
        _SERVER = None


_SERVER: CommandServer | None = None


def command_server() -> CommandServer | None:
    """The session's command server (none with ADADEMO_TESTS_NO_FORK=1: every command is a fresh interpreter)."""
    global _SERVER
    if _SERVER is None and os.environ.get("ADADEMO_TESTS_NO_FORK") != "1" and hasattr(os, "fork"):
        _SERVER = CommandServer()
    return _SERVER


def pytest_sessionfinish(session, exitstatus):
    if _SERVER is not None:
        _SERVER.close()
    if _CALIBRATION_DIR is not None:
        shutil.rmtree(_CALIBRATION_DIR, ignore_errors=True)


def run_cli(command: str, *args: str, check: bool = True, timeout: int = 900) -> subprocess.CompletedProcess:
    """Run one of our (or LeRobot's) console scripts as a user would: its entry point, its own process, argv,
    working directory, output and exit code (forked from the command server, which saves the import time)."""
    server = command_server()
    if server is not None and server.can_run():
        proc = server.run(command, list(args), timeout)
    else:
        proc = subprocess.run([str(BIN / command), *args], capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"{command} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def assert_cli_error(command: str, *args: str, match: str) -> str:
    """The command must refuse the input with exit code 2 and one `error:` line naming the problem."""
    proc = run_cli(command, *args, check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert "error:" in last and match in last, last
    return last


@pytest.fixture(scope="session")
def reach_push_dataset(tmp_path_factory) -> Path:
    """The issue's example: 3 demos each of reach-v3 and push-v3, collected by `adademo-collect`."""
    root = tmp_path_factory.mktemp("collect") / "demo"
    run_cli(
        "adademo-collect",
        "--suite.type=metaworld",
        "--suite.tasks=reach-v3,push-v3",
        "--episodes_per_task=3",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        "--seed=0",
    )
    return root


def file_digests(root: Path) -> dict[str, str]:
    import hashlib

    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def lerobot_files(root: Path) -> dict[str, str]:
    """`file_digests` of the dataset's LeRobot files: everything but our own folder (journals, shards)."""
    from adademo_lerobot.dataset.layout import ADADEMO_DIR

    return {k: v for k, v in file_digests(root).items() if not k.startswith(ADADEMO_DIR + "/")}


def stock_episodes(root: Path, repo_id: str = "local/demo") -> int:
    """The dataset opened by stock LeRobot: its episode count."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, root=root).num_episodes


def mount_small_disk(path: Path, size: str) -> None:
    path.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True
    )
    if proc.returncode != 0:
        message = f"cannot mount a small tmpfs here ({proc.stderr.decode().strip()})"
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI must run the full-disk tests: {message}")
        pytest.skip(message)


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB filesystem (a real full disk: tests mount it as root, as on the project's machines and in CI;
    elsewhere they are skipped, but not in CI), unmounted afterwards."""
    disk = tmp_path / "disk"
    mount_small_disk(disk, "1m")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def leave_free(disk: Path, free_bytes: int) -> Path:
    """Fill `disk` with a file so that about `free_bytes` stay free; returns the file (delete it to free space)."""
    st = os.statvfs(disk)
    filler = disk / "filler"
    with open(filler, "wb") as f:
        f.write(b"\0" * max(0, st.f_bavail * st.f_frsize - free_bytes))
    return filler


TINY_ACT_POLICY = [
    "--policy.type=act",
    "--policy.dim_model=32",
    "--policy.dim_feedforward=64",
    "--policy.n_heads=2",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.n_vae_encoder_layers=1",
    "--policy.chunk_size=10",
    "--policy.n_action_steps=5",
    "--policy.device=cpu",
]
TINY_ACT = [*TINY_ACT_POLICY, "--batch_size=8"]


def stock_tiny_train(root: Path, output_dir: Path) -> Path:
    """Two steps of stock `lerobot-train` on the dataset at `root` (a tiny ACT, nothing downloaded); returns the
    checkpoint's pretrained_model folder."""
    run_cli(
        "lerobot-train",
        "--dataset.repo_id=local/robot",
        f"--dataset.root={root}",
        *TINY_ACT_POLICY,
        "--policy.pretrained_backbone_weights=null",  # no download at run time
        "--policy.push_to_hub=false",
        "--batch_size=4",
        "--steps=2",
        "--save_freq=2",
        f"--output_dir={output_dir}",
        "--num_workers=0",
        "--env_eval_freq=0",
        "--wandb.enable=false",
    )
    return output_dir / "checkpoints" / "last" / "pretrained_model"


@pytest.fixture(scope="session")
def act_run(reach_push_dataset, tmp_path_factory):
    """A weak ACT (4 steps) trained by `adademo-train` on the reach/push dataset."""
    out = tmp_path_factory.mktemp("act") / "run"
    run_cli(
        "adademo-train",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={reach_push_dataset}",
        *TINY_ACT,
        "--steps=4",
        "--save_freq=2",
        f"--output_dir={out}",
        "--sampler=trajectory",
        "--min_task_weight=0.3",
    )
    return out


@pytest.fixture(scope="session")
def ckpt(act_run) -> Path:
    """The weak ACT's last checkpoint (`act_run`)."""
    return act_run / "checkpoints" / "last" / "pretrained_model"


@pytest.fixture
def dataset(reach_push_dataset, tmp_path) -> Path:
    """A copy of the reach/push dataset the test may change."""
    root = tmp_path / "ds"
    shutil.copytree(reach_push_dataset, root)
    return root


def expand(root: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    """`adademo-expand` on the dataset at `root` (repo id local/demo)."""
    return run_cli(
        "adademo-expand", "--dataset.repo_id=local/demo", f"--dataset.root={root}", *args, check=check
    )


@pytest.fixture(scope="session")
def stock_act_checkpoint(reach_push_dataset, tmp_path_factory) -> Path:
    """An ACT trained for 2 steps by stock `lerobot-train` on the reach/push dataset."""
    out = tmp_path_factory.mktemp("stock") / "run"
    run_cli(
        "lerobot-train",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={reach_push_dataset}",
        *TINY_ACT,
        "--steps=2",
        "--save_freq=2",
        f"--output_dir={out}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--env_eval_freq=0",
        "--wandb.enable=false",
        timeout=600,
    )
    return out / "checkpoints" / "last" / "pretrained_model"


def episode_frames(root, episode_index):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/demo", root=root, episodes=[episode_index])
    return {
        key: np.stack([np.asarray(x) for x in ds.hf_dataset[key]])
        for key in ("observation.environment_state", "observation.state", "action")
    }


def replay(suite, root, episode_index, row) -> None:
    """An episode of the dataset, replayed from what it records: from its start state (a correction) or its
    initial state, its actions reproduce its observations and end in success."""
    frames = episode_frames(root, episode_index)
    env = suite.make_env(row["task"], terminate_on_success=False)
    obs, _ = env.reset(options={"state": row["adademo/start_state"], "new_episode": True})
    success = False
    for t, action in enumerate(frames["action"]):
        np.testing.assert_allclose(
            obs["environment_state"], frames["observation.environment_state"][t], atol=1e-6
        )
        np.testing.assert_allclose(obs["agent_pos"], frames["observation.state"][t], atol=1e-6)
        obs, _, _, _, info = env.step(action)
        success |= info["is_success"]
    assert success, f"episode {episode_index} does not end in success on replay"


@pytest.fixture(scope="session")
def reach(tmp_path_factory):
    """10 reach-v3 demonstrations and an ACT trained on them for 400 steps (it succeeds on ~25 % of states)."""
    base = tmp_path_factory.mktemp("keep")
    root = base / "ds"
    run_cli(
        "adademo-collect",
        "--suite.type=metaworld",
        "--suite.tasks=reach-v3",
        "--episodes_per_task=10",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        "--seed=0",
    )
    run_cli(
        "adademo-train",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        *TINY_ACT_POLICY,
        "--batch_size=16",
        "--steps=400",
        "--save_freq=400",
        f"--output_dir={base / 'train'}",
        "--torch_threads=1",
    )
    return root, base / "train" / "checkpoints" / "last" / "pretrained_model"
