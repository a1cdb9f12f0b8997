"""`--executor=ray` against `--executor=local` on a local Ray cluster this module starts: the same initial states,
outcomes, dataset episodes (same actions, same order) and ledger, whatever the number of workers; and faults:
a worker killed mid-round, the driver killed mid-round and Ctrl-C mid-round, each followed by a complete, identical
round."""

from __future__ import annotations

import importlib.util
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from conftest import BIN, lerobot_files, run_cli, stock_episodes

from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata

pytest.importorskip("ray")


@pytest.fixture(scope="module")
def ray_address(tmp_path_factory):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # Ray authenticates clients of its clusters with a token; the cluster and every command here share this one.
    saved = {k: os.environ.get(k) for k in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")}
    os.environ.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16))
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    temp = tmp_path_factory.mktemp("ray")
    proc = subprocess.run(
        [
            str(BIN / "ray"),
            "start",
            "--head",
            f"--port={port}",
            "--num-cpus=2",
            "--include-dashboard=false",
            "--disable-usage-stats",
            f"--temp-dir={temp}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    yield f"127.0.0.1:{port}"
    subprocess.run([str(BIN / "ray"), "stop", "--force"], capture_output=True, timeout=120, env=env)
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def ray_flags(address: str, workers: int = 2) -> list[str]:
    return ["--executor=ray", f"--ray.address={address}", f"--ray.num_workers={workers}"]


def frames_by_episode(root: Path) -> dict[tuple[str, int], np.ndarray]:
    eps = read_episode_metadata(root)
    data = pd.concat(pq.read_table(p).to_pandas() for p in sorted((root / "data").rglob("*.parquet")))
    actions = {}
    for index, row in eps.iterrows():
        rows = data[data.episode_index == index]
        actions[(row.task, int(row["adademo/seed"]))] = np.stack(rows["action"].to_numpy())
    return actions


def same_round(a: Path, b: Path, round_index: int) -> None:
    """Two datasets that ran the same round: same episodes in the same order with the same actions, the same
    ledger (but wall time) and the same evaluation outcomes."""
    ea, eb = read_episode_metadata(a), read_episode_metadata(b)
    assert list(zip(ea.task, ea["adademo/seed"], strict=True)) == list(
        zip(eb.task, eb["adademo/seed"], strict=True)
    )
    fa, fb = frames_by_episode(a), frames_by_episode(b)
    for key in fa:
        np.testing.assert_array_equal(fa[key], fb[key])

    def ledger(root):
        return [{k: v for k, v in r.items() if k != "wall_seconds"} for r in read_ledger(root)]

    assert ledger(a) == ledger(b)

    def outcomes(root):
        return sorted(
            (e["type"], e["task"], e["seed"], e.get("success"), e.get("steps"))
            for e in read_round_evaluations(root, round_index)
            if e["type"] in ("eval", "expert_failure")
        )

    assert outcomes(a) == outcomes(b)


ADADEMO = ["--strategy.type=adademo", "--strategy.target_successes=2", "--strategy.max_demos_per_task=4"]


def expand_args(root: Path, ckpt: Path, strategy: list[str] = ADADEMO) -> list[str]:
    return [
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        f"--policy.path={ckpt}",
        *strategy,
        "--eval.batch_size=3",
        "--commit_every=2",
    ]


def test_ray_gives_the_same_round_as_local(reach_push_dataset, ckpt, ray_address, tmp_path):
    local, remote = tmp_path / "local", tmp_path / "ray"
    shutil.copytree(reach_push_dataset, local)
    shutil.copytree(reach_push_dataset, remote)
    run_cli("adademo-expand", *expand_args(local, ckpt))
    done = run_cli("adademo-expand", *expand_args(remote, ckpt), *ray_flags(ray_address))
    same_round(local, remote, 1)
    added = len(read_episode_metadata(local)) - 6
    assert added > 0  # the round did add demos
    # The workers wrote them (shards, merged by the driver: frames never came back), and no shard is left.
    assert f"({added} written by the Ray workers, merged here)" in done.stdout
    assert not remote.with_name(f".{remote.name}.adademo-shards").exists()
    check_dataset_integrity(remote)

    # Corrections: the takeover is chosen on the worker that ran the rollout, the correction on any worker.
    takeover = ["--strategy.type=budgeted", "--strategy.budget=4"]
    run_cli("adademo-expand", *expand_args(local, ckpt, takeover), "--demo_start=takeover")
    run_cli(
        "adademo-expand",
        *expand_args(remote, ckpt, takeover),
        "--demo_start=takeover",
        *ray_flags(ray_address),
    )
    same_round(local, remote, 2)
    ea, eb = read_episode_metadata(local), read_episode_metadata(remote)
    assert (ea[ea["adademo/round"] == 2]["adademo/source"] == "correction").all()
    for sa, sb in zip(ea["adademo/start_state"], eb["adademo/start_state"], strict=True):
        np.testing.assert_array_equal(sa, sb)


def test_units_asked_together_go_out_a_few_per_call_the_same_share_for_every_worker():
    from adademo_lerobot.executors.ray_executor import MAX_UNITS_PER_CALL, call_sizes

    assert call_sizes(6, 2) == [3, 3]  # one call per worker
    assert call_sizes(7, 2) == [4, 3]
    assert call_sizes(3, 64) == [1, 1, 1]  # fewer units than workers: one each
    assert call_sizes(0, 2) == []
    assert call_sizes(17, 2) == [5, 4, 4, 4]  # not 8 + 8 + 1: each worker gets 9 or 8 units
    assert call_sizes(100, 4) == [7] * 4 + [6] * 12  # 16 calls, 4 per worker: 25 units each
    for units, workers in [(1000, 2), (160, 6), (5, 1), (9, 1), (65, 8)]:
        sizes = call_sizes(units, workers)
        assert sum(sizes) == units and max(sizes) <= MAX_UNITS_PER_CALL and max(sizes) - min(sizes) <= 1
        assert len(sizes) % workers == 0 or len(sizes) == units


def run_driver_script(script: str, ray_address: str, ckpt: Path) -> dict:
    """`script` run as a Ray driver process of its own (as a command is), given the cluster and checkpoint: the
    last JSON object it prints."""
    out = subprocess.run(
        [str(BIN / "python"), "-c", script, ray_address, str(ckpt)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(next(line for line in reversed(out.stdout.splitlines()) if line.startswith("{")))


PLACEMENT = """
import json, sys
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.executors import RayArgs
from adademo_lerobot.executors.ray_executor import RayExecutor
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

address, ckpt = sys.argv[1:]
suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3", max_episode_steps=100))
import signal
from adademo_lerobot.core.interrupts import raise_keyboard_interrupt
signal.signal(signal.SIGTERM, raise_keyboard_interrupt)  # as the commands set it
executor = RayExecutor(RayArgs(address=address, num_workers=2), suite, ScriptedCollectorConfig(), 2, "cpu")
sigterm_kept = signal.getsignal(signal.SIGTERM) is raise_keyboard_interrupt  # ray.init replaces it
executor.use_policy(ckpt)
def worker_of(ref):
    return next(i for i, calls in enumerate(executor._inflight) if any(r == ref for r, _ in calls))
placed = []
for k, task in enumerate(["reach-v3", "push-v3"] * 3):
    pending = executor.evaluate(task, [k])
    placed.append([task, worker_of(pending.ref)])
    pending.result()
burst = []  # units submitted together, none read yet: spread by load, a few per call
for pending in executor.collect_many("reach-v3", [(100 + k, None) for k in range(6)]):
    burst.append((pending, worker_of(pending.call.ref), pending.call.ref.hex()))
single = executor.collect("reach-v3", 103)  # alone in its call
def actions(result):
    return [f["action"].tolist() for f in result.demonstration.frames]
same = actions(burst[3][0].result()) == actions(single.result())
for pending, _, _ in burst:
    pending.result()
executor._drop_finished()
print(json.dumps({"placed": placed, "burst": [i for _, i, _ in burst], "calls": len({c for _, _, c in burst}),
                  "same": same, "left": executor._load, "sigterm_kept": sigterm_kept}))
executor.close()
"""


def test_a_tasks_units_go_to_the_worker_that_ran_it_last(ray_address, ckpt):
    """Units submitted one at a time, as strategies evaluate the tasks in turn: each task keeps to one worker
    (whose envs for it are still built), and a task no worker has run goes to the one idle longest (by load
    alone, every unit went to worker 0, which built new envs for each). Units submitted together spread over
    the workers, a few per call, and finished ones stop counting."""
    result = run_driver_script(PLACEMENT, ray_address, ckpt)
    placed = result["placed"]
    workers = {task: {i for t, i in placed if t == task} for task in ("reach-v3", "push-v3")}
    assert all(len(w) == 1 for w in workers.values()), placed
    assert workers["reach-v3"] != workers["push-v3"], placed
    assert result["burst"] == [0, 0, 0, 1, 1, 1] or result["burst"] == [1, 1, 1, 0, 0, 0], result
    assert result["calls"] == 2, result  # 6 units, 2 workers: 3 per call, one call per worker
    assert result["same"], result  # a unit's demonstration does not depend on the call that carried it
    assert result["left"] == [0, 0], result  # finished units are no longer counted
    assert result["sigterm_kept"], result  # SIGTERM still stops a command as Ctrl-C does, after ray.init


STOP_WAITING = """
import json, sys, threading, time
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.core.errors import RoundAbortedError
from adademo_lerobot.executors import RayArgs
from adademo_lerobot.executors.ray_executor import RayExecutor
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

address, ckpt = sys.argv[1:]
suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3", max_episode_steps=500))
executor = RayExecutor(RayArgs(address=address, num_workers=1), suite, ScriptedCollectorConfig(), 2, "cpu")
executor.use_policy(ckpt)
pending = executor.evaluate("push-v3", list(range(60)))  # one long unit: 60 episodes of up to 500 steps
seen = {}
def wait():
    try:
        pending.result()
        seen["ended"] = "with the result"
    except RoundAbortedError:
        seen["ended"] = "given up"
    seen["at"] = time.perf_counter()
waiter = threading.Thread(target=wait)
waiter.start()
time.sleep(2)
running = not pending.ready()
stopped_at = time.perf_counter()
executor.stop_waiting()
waiter.join(timeout=60)
print(json.dumps({"running": running, "ended": seen.get("ended"), "after": seen["at"] - stopped_at}))
executor.close()
"""


def test_a_round_that_stops_gives_up_the_units_it_waits_for_at_once(ray_address, ckpt):
    """Ctrl-C (or a failed task) during a Ray round: a task's loop waiting for a long unit ends within a second,
    not when the unit is done (an evaluation batch or a planner's demonstrations can take minutes)."""
    result = run_driver_script(STOP_WAITING, ray_address, ckpt)
    assert result["running"], result  # the unit was still running when the round stopped
    assert result["ended"] == "given up" and result["after"] < 3, result


@pytest.mark.slow
def test_ray_gives_the_same_fresh_state_rounds_as_local(reach_push_dataset, ckpt, ray_address, tmp_path):
    """Uniform (fresh states, no policy) then task_only, two rounds each way."""
    local, remote = tmp_path / "local", tmp_path / "ray"
    shutil.copytree(reach_push_dataset, local)
    shutil.copytree(reach_push_dataset, remote)
    for strategy in (
        ["--strategy.type=uniform", "--strategy.demos_per_task=2"],
        ["--strategy.type=task_only", "--strategy.target_successes=1", "--strategy.plan_episodes_per_task=3"],
    ):
        run_cli("adademo-expand", *expand_args(local, ckpt, strategy))
        run_cli("adademo-expand", *expand_args(remote, ckpt, strategy), *ray_flags(ray_address))
    same_round(local, remote, 2)
    assert len(read_episode_metadata(local)) > 6


@pytest.mark.slow
def test_fixed_set_evaluation_and_collection_are_the_same_with_any_number_of_workers(
    ckpt, reach_push_dataset, ray_address, tmp_path
):
    outputs = {}
    for name, flags in (
        ("local", []),
        ("ray1", ray_flags(ray_address, 1)),
        ("ray2", ray_flags(ray_address, 2)),
    ):
        run_cli(
            "adademo-eval",
            f"--policy.path={ckpt}",
            f"--dataset.root={reach_push_dataset}",
            "--episodes_per_task=5",
            "--eval.batch_size=2",
            f"--output_dir={tmp_path / name}",
            *flags,
        )
        outputs[name] = pd.read_parquet(tmp_path / name / "eval_episodes.parquet")
    for name in ("ray1", "ray2"):
        pd.testing.assert_frame_equal(outputs["local"], outputs[name])

    roots = {}
    for name, flags in (
        ("local", []),
        ("ray2", ray_flags(ray_address, 2)),
        ("ray_frames", [*ray_flags(ray_address, 1), "--ray.worker_writes=false"]),  # pickled demonstrations
    ):
        roots[name] = tmp_path / f"collect_{name}"
        run_cli(
            "adademo-collect",
            "--suite.tasks=reach-v3,push-v3,drawer-open-v3",
            "--episodes_per_task=2",
            "--dataset.repo_id=local/c",
            f"--dataset.root={roots[name]}",
            "--seed=5",
            "--commit_every=1",
            *flags,
        )
    ea = read_episode_metadata(roots["local"])
    assert (
        list(ea.task) == ["reach-v3"] * 2 + ["push-v3"] * 2 + ["drawer-open-v3"] * 2
    )  # suite order, as local
    fa = frames_by_episode(roots["local"])
    for name in ("ray2", "ray_frames"):
        assert list(ea["adademo/seed"]) == list(read_episode_metadata(roots[name])["adademo/seed"])
        fb = frames_by_episode(roots[name])
        assert fa.keys() == fb.keys() and all(np.array_equal(fa[k], fb[k]) for k in fa)


@pytest.mark.slow  # the default suite's budget: a Ray claim, as most of this module's
def test_a_plugin_expert_records_the_same_demonstrations_on_ray_workers(ray_address, tmp_path):
    """The workers import a plugin's expert when they get one (docs/extending.md): examples/adademo_lerobot_example's
    `--collector.type=smoothed` gives the same episodes on two workers as in the driver's process."""
    if importlib.util.find_spec("adademo_lerobot_example") is None:
        if os.environ.get("CI") == "true":
            pytest.fail("CI must run the plugin tests: examples/adademo_lerobot_example is not installed")
        pytest.skip(
            "the plugin example is not installed (pip install --no-deps -e examples/adademo_lerobot_example)"
        )
    roots = {}
    for name, flags in (("local", []), ("ray", ray_flags(ray_address, 2))):
        roots[name] = tmp_path / name
        run_cli(
            "adademo-collect", "--suite.tasks=reach-v3,push-v3", "--episodes_per_task=2",
            "--collector.type=smoothed", "--dataset.repo_id=local/c", f"--dataset.root={roots[name]}", *flags,
        )  # fmt: skip
    local, remote = read_episode_metadata(roots["local"]), read_episode_metadata(roots["ray"])
    assert set(remote["adademo/collector"]) == {"smoothed-metaworld-scripted"}
    assert list(local["adademo/seed"]) == list(remote["adademo/seed"])
    fa, fb = frames_by_episode(roots["local"]), frames_by_episode(roots["ray"])
    assert fa.keys() == fb.keys() and all(np.array_equal(fa[k], fb[k]) for k in fa)


def worker_pids() -> list[int]:
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [int(line.split()[0]) for line in out.splitlines() if "ray::EpisodeWorker" in line]


def wait_for(condition, what: str, proc: subprocess.Popen, timeout: float = 300) -> None:
    deadline = time.time() + timeout
    while not condition():
        assert time.time() < deadline and proc.poll() is None, f"{what} did not happen"
        time.sleep(0.1)


def evaluations_so_far(root: Path, kind: str = "eval") -> int:
    journal = root / "meta" / "adademo" / "journal-round-001.jsonl"
    return (
        sum(f'"type": "{kind}"' in line for line in journal.read_text().splitlines())
        if journal.exists()
        else 0
    )


def reference_round_and_copy(dataset: Path, ckpt, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the dataset expanded locally without faults (the reference) and an untouched copy."""
    reference, other = tmp_path / "reference", tmp_path / "other"
    shutil.copytree(dataset, reference)
    shutil.copytree(dataset, other)
    run_cli("adademo-expand", *expand_args(reference, ckpt))
    return reference, other


@pytest.mark.slow
def test_a_killed_worker_is_replaced_and_the_round_is_complete_and_the_same(
    reach_push_dataset, ckpt, ray_address, tmp_path
):
    reference, faulty = reference_round_and_copy(reach_push_dataset, ckpt, tmp_path)
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *expand_args(faulty, ckpt), *ray_flags(ray_address)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    wait_for(lambda: evaluations_so_far(faulty) >= 1 and worker_pids(), "the first evaluations", proc)
    victim = worker_pids()[0]
    os.kill(victim, signal.SIGKILL)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert victim not in worker_pids()
    same_round(reference, faulty, 1)  # nothing lost, nothing twice


@pytest.mark.slow
def test_a_killed_driver_resumes_from_the_journal_to_the_same_round(
    reach_push_dataset, ckpt, ray_address, tmp_path
):
    reference, resumed = reference_round_and_copy(reach_push_dataset, ckpt, tmp_path)
    args = [*expand_args(resumed, ckpt), *ray_flags(ray_address)]
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    # Killed once it has committed shards to its journal (merged later, 100 at a time, or at the round's end).
    wait_for(lambda: evaluations_so_far(resumed, "shards") >= 1, "a commit of shards", proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not read_ledger(resumed)  # the round was cut short
    journal = resumed / "meta" / "adademo" / "journal-round-001.jsonl"
    committed = [
        (task, seed)
        for line in journal.read_text().splitlines()
        if '"type": "shards"' in line
        for _, task, seed in json.loads(line)["shards"]
    ]
    run_cli("adademo-expand", *args)
    same_round(reference, resumed, 1)
    # The rerun merged what the killed run committed: none of those demonstrations was collected again.
    demos = [(e["task"], e["seed"]) for e in read_round_evaluations(resumed, 1) if e["type"] == "demo"]
    assert committed and all(demos.count(key) == 1 for key in committed)
    state = json.loads((resumed / "meta" / "info.json").read_text())
    assert state["total_episodes"] == len(read_episode_metadata(reference))


@pytest.mark.slow
def test_ctrl_c_in_a_ray_round_stops_within_seconds_leaves_the_dataset_as_it_was_and_the_rerun_finishes_it(
    reach_push_dataset, ckpt, ray_address, tmp_path
):
    """Ctrl-C while the workers evaluate, the whole command: it exits 130 with one line within seconds (2.5 s here;
    a long unit given up at once is the test above), leaves the dataset's LeRobot files as they were (stock LeRobot
    opens it), and the same command then finishes the round as an uninterrupted one does."""
    reference, stopped = reference_round_and_copy(reach_push_dataset, ckpt, tmp_path)
    before = lerobot_files(stopped)
    args = [*expand_args(stopped, ckpt), *ray_flags(ray_address)]
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # Ctrl-C as in a terminal, even when the suite itself runs in the background (which ignores SIGINT).
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    wait_for(lambda: evaluations_so_far(stopped) >= 1, "the first evaluations", proc)
    proc.send_signal(signal.SIGINT)
    signalled = time.perf_counter()
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr[-3000:]
    assert time.perf_counter() - signalled < 30, "the command hung as it stopped"
    last = stderr.replace("\r", "\n").strip().splitlines()[-1]
    assert "Traceback" not in stderr, stderr[-3000:]
    assert last.startswith("interrupted: rerun the same command"), last
    assert lerobot_files(stopped) == before and not read_ledger(stopped)
    assert stock_episodes(stopped) == len(read_episode_metadata(reach_push_dataset))  # stock LeRobot opens it
    run_cli("adademo-expand", *args)
    same_round(reference, stopped, 1)


@pytest.mark.slow
def test_ray_keeps_the_same_successful_rollouts_as_local(reach, ray_address, tmp_path):
    """--keep_successes on Ray: the workers write the kept rollouts as shards (merged, marked as the policy's)."""
    source, ckpt = reach
    local, remote = tmp_path / "local", tmp_path / "ray"
    shutil.copytree(source, local)
    shutil.copytree(source, remote)
    keep = [
        "--strategy.type=adademo",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=20",
        "--strategy.max_eval_episodes_per_task=40",
        "--keep_successes=true",
    ]
    run_cli("adademo-expand", *expand_args(local, ckpt, keep))
    done = run_cli("adademo-expand", *expand_args(remote, ckpt, keep), *ray_flags(ray_address))
    same_round(local, remote, 1)
    eps = read_episode_metadata(remote)
    kept = eps[eps["adademo/source"] == "policy"]
    assert len(kept) >= 1 and (kept["adademo/collector"] == "").all()
    assert f"({len(eps) - 10} written by the Ray workers, merged here)" in done.stdout
    check_dataset_integrity(remote)
