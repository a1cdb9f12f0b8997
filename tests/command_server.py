"""Runs console scripts (ours and LeRobot's) for the tests in forks of one process that has already imported
torch, LeRobot and the simulators, so each command starts in milliseconds instead of seconds.

Each command still runs in its own process, from its real entry point, with its own argv, working directory,
stdout, stderr and exit code: exactly what a user's shell would run, minus the import time. The server imports
nothing that starts threads (no torch op runs before a fork). Commands whose environment changes import-time
settings (a hub endpoint, a GL backend, ...) are not sent here: conftest runs those as plain subprocesses.

    python tests/command_server.py      # speaks one JSON request / reply per line on stdin / stdout
"""

from __future__ import annotations

import atexit
import json
import os
import sys
import tempfile
import time
import traceback
from importlib import metadata


def preload() -> None:
    from adademo_lerobot.core.gl import prefer_loadable_backend

    prefer_loadable_backend()  # as a command does, before anything imports MuJoCo
    import lerobot.datasets.lerobot_dataset  # noqa: F401
    import lerobot.policies  # noqa: F401
    import lerobot.scripts.lerobot_eval  # noqa: F401
    import lerobot.scripts.lerobot_record  # noqa: F401
    import metaworld  # noqa: F401
    import torch  # noqa: F401

    import adademo_lerobot.loop.collect  # noqa: F401
    import adademo_lerobot.loop.evaluate  # noqa: F401
    import adademo_lerobot.loop.expand  # noqa: F401
    import adademo_lerobot.loop.record  # noqa: F401
    import adademo_lerobot.loop.report  # noqa: F401
    import adademo_lerobot.loop.run  # noqa: F401
    import adademo_lerobot.loop.train  # noqa: F401


def entry_point(command: str):
    (ep,) = metadata.entry_points(group="console_scripts", name=command)
    return ep.load()


def run_child(request: dict, out_path: str, err_path: str) -> None:
    out, err = os.open(out_path, os.O_WRONLY), os.open(err_path, os.O_WRONLY)
    os.dup2(out, 1)
    os.dup2(err, 2)
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])  # the test's environment at the time of the command
    sys.argv = [request["command"], *request["args"]]
    code = 0
    try:
        entry_point(request["command"])()
    except SystemExit as exit:
        if isinstance(exit.code, str):
            print(exit.code, file=sys.stderr)
            code = 1
        else:
            code = exit.code or 0
    except BaseException:  # noqa: BLE001  (a crash is reported like an interpreter's: traceback, exit 1)
        traceback.print_exc()
        code = 1
    try:
        atexit._run_exitfuncs()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def serve() -> None:
    preload()
    print(json.dumps({"ready": os.getpid()}), flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        out = tempfile.NamedTemporaryFile("w", delete=False, suffix=".out")  # noqa: SIM115
        err = tempfile.NamedTemporaryFile("w", delete=False, suffix=".err")  # noqa: SIM115
        out.close()
        err.close()
        pid = os.fork()
        if pid == 0:
            run_child(request, out.name, err.name)
        deadline = time.monotonic() + request["timeout"]
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if time.monotonic() > deadline:
                os.kill(pid, 9)
                _, status = os.waitpid(pid, 0)
                break
            time.sleep(0.01)
        code = os.waitstatus_to_exitcode(status)
        reply = {"id": request["id"], "returncode": code, "stdout": out.name, "stderr": err.name}
        print(json.dumps(reply), flush=True)


if __name__ == "__main__":
    serve()
