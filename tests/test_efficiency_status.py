"""benchmarks/data_efficiency.py status: where each run folder of a days-long table stands, read from the files
adademo-run leaves (its run state and each round's evaluation summary)."""

import json
import re
import sys
from contextlib import ExitStack

import pytest
from conftest import load_benchmark

bench = load_benchmark("data_efficiency")


def run_folder(root, done, rates_by_round, settings=None):
    """A run folder's run state and evaluation summaries, in the shape adademo-run writes them."""
    root.mkdir(parents=True)
    (root / "run_state.json").write_text(json.dumps({"settings": settings or {}, "done": done}))
    for r, rates in enumerate(rates_by_round):
        folder = root / "eval" / f"round-{r:03d}"
        folder.mkdir(parents=True)
        rows = [
            {"task": t, "episodes": 50, "success_rate": rate} for t, rate in zip("ab", rates, strict=True)
        ] + [{"task": "average", "episodes": 100, "success_rate": sum(rates) / 2}]
        (folder / "eval_summary.json").write_text(json.dumps({"round": r, "per_task": rows}))


def test_status_lists_each_run_with_its_rounds_and_added_demonstrations(tmp_path, capsys):
    base = {
        "collect": {"result": {}, "seconds": 3600.0},
        "train-0": {"result": "x", "seconds": 1800.0},
        "eval-0": {"result": {}, "seconds": 360.0},
    }
    expand = {
        f"expand-{r}": {"result": {"demos_added": {"a": r, "b": 2 * r}}, "seconds": 720.0} for r in (1, 2, 3)
    }
    rounds = {f"{k}-{r}": {"result": {}, "seconds": 360.0} for r in (1, 2, 3) for k in ("train", "eval")}
    run_folder(tmp_path / "seed1" / "base", base, [(0.5, 0.25)])
    run_folder(
        tmp_path / "seed1" / "uniform", base | expand | rounds, [(0.5, 0.25), (0.5, 0.5), (1, 0.5), (1, 1)]
    )
    partial = base | {"expand-1": expand["expand-1"], "train-1": {"result": "y", "seconds": 360.0}}
    run_folder(tmp_path / "seed2" / "adademo", partial, [(0.0, 0.5)])
    run_folder(tmp_path / "seed2" / "budgeted.copying", base, [(0.0, 0.5)])

    status = bench.arm_status(tmp_path / "seed1" / "uniform")
    assert status["finished"] and status["added"] == 18 and status["averages"] == [37.5, 50.0, 75.0, 100.0]
    assert status["hours"] == 1.2  # its own rounds 1-3 (3 x 0.2 + 6 x 0.1), not the base's 1.6 copied with it
    bench.phase_status(tmp_path)
    rows = capsys.readouterr().out.strip().splitlines()[2:]
    assert rows == [
        "| seed1 | base | eval-0 done | 37.5 | 0 | 1.6 |",
        "| seed1 | uniform | finished | 37.5 -> 50.0 -> 75.0 -> 100.0 | 18 | 1.2 |",
        "| seed2 | adademo | train-1 done | 25.0 | 3 | 0.3 |",  # the copy of a branch in progress is left out
    ]


FINISHED = [(0.5, 0.25)] * 4  # rounds 0-3 evaluated


def test_arms_runs_arm_by_arm_over_the_seeds_each_seed_s_base_first(tmp_path, monkeypatch):
    """The first arms get every seed before the next arm starts (what a report pairs); an arm with a summary is
    done wherever it ran, and a seed with nothing left due gets no base."""
    summaries = tmp_path / "summaries"
    summaries.mkdir()
    monkeypatch.setattr(bench, "SUMMARIES", summaries)
    out = tmp_path / "out"
    run_folder(out / "seed1" / "base", {}, FINISHED[:1])
    run_folder(out / "seed1" / "uniform", {}, FINISHED)
    run_folder(out / "seed1" / "adademo", {}, FINISHED[:2])  # in its round 1
    arms = ["uniform", "adademo"]
    assert bench.pending_runs(out, [1, 2], arms) == [out / "seed2" / "base", out / "seed1" / "adademo"]
    (summaries / "seed2-uniform.json").write_text("{}")
    (summaries / "seed2-adademo.json").write_text("{}")
    assert bench.pending_runs(out, [1, 2], arms) == [out / "seed1" / "adademo"]
    # A recipe of one round: its arm is finished after round 1, its base after round 0.
    run_folder(out / "seed3" / "base", {}, FINISHED[:1], settings={"rounds": 0})
    run_folder(out / "seed3" / "uniform", {}, FINISHED[:2], settings={"rounds": 1})
    assert bench.pending_runs(out, [3], arms) == [out / "seed3" / "adademo"]


def test_drivers_of_one_command_share_its_runs(tmp_path, monkeypatch, capsys):
    """`arms` started twice takes, in each driver, the next run the other does not hold; a driver with nothing
    left to take waits only for a base whose arms follow, then ends."""
    import threading

    monkeypatch.setattr(bench, "SUMMARIES", tmp_path / "summaries")  # none: nothing to pair with
    out = tmp_path / "out"
    run_folder(out / "seed1" / "base", {}, FINISHED[:1])
    run_folder(out / "seed1" / "uniform", {}, FINISHED)
    arms = ["uniform", "adademo"]
    with bench.claimed(out / "seed1" / "adademo") as first:
        with bench.claimed(out / "seed1" / "adademo") as second:  # another driver (its own open file)
            assert first and not second
        with bench.claimed(out / "seed1" / "uniform") as other_run:
            assert other_run
    with bench.claimed(out / "seed1" / "adademo") as after:  # released when its holder is done with it
        assert after

    # Another driver holds every run left, seed 2's base among them: this one waits for that base, finds seed 2's
    # arms due, held as well, and ends without running anything.
    (out / "seed2").mkdir()
    held = [out / "seed1" / "adademo", *(out / "seed2" / name for name in ("base", *arms))]
    with ExitStack() as stack:
        holds = [stack.enter_context(open(run.parent / f"{run.name}.lock", "w")) for run in held]
        for hold in holds:
            bench.fcntl.flock(hold, bench.fcntl.LOCK_EX)

        def other_driver_builds_the_base():
            run_folder(out / "seed2" / "base", {}, FINISHED[:1])
            holds[1].close()

        builder = threading.Timer(0.5, other_driver_builds_the_base)
        builder.start()
        bench.phase_arms(out, [1, 2], arms)
        builder.join()
    printed = capsys.readouterr().out
    assert f"waiting for another driver's {out / 'seed2' / 'base'}" in printed
    assert "the 3 runs left are held by another driver" in printed  # seed 1's adademo, seed 2's two arms
    assert not (out / "seed2" / "uniform").exists()


def uniform_summary(seed: int, machine: str, round0: tuple[float, float]) -> str:
    return json.dumps(
        {
            "arm": "uniform",
            "seed": seed,
            "machine": machine,
            "success": {t: [r, 0.9] for t, r in zip("ab", round0, strict=True)},
        }
    )


def test_a_seed_runs_only_where_its_arms_pair_with_the_ones_summarised(tmp_path, monkeypatch):
    """MKL's AMD kernels train other policies than its Intel ones: refused before hours go into a base; with the
    kernels the seed ran with, the base is built, then its round 0 must equal the one its summaries started from."""
    here = bench.machine_line()  # this test process: no kernel settings of the benchmarks
    assert bench.mkl_kernels("x86_64 AMD EPYC (AVX-512, kernels pinned to AVX2, MKL's Intel path)") == "Intel"
    assert bench.mkl_kernels("x86_64 Intel(R) Xeon(R) Processor (AVX-512, kernels pinned to AVX2)") == "Intel"
    assert bench.mkl_kernels("x86_64 AMD EPYC (AVX2)") == "AMD"
    other = (
        "AMD EPYC (AVX2)"
        if bench.mkl_kernels(bench.cpu_of(here)) == "Intel"
        else "AMD EPYC (AVX2, MKL's Intel path)"
    )
    summaries = tmp_path / "summaries"
    summaries.mkdir()
    monkeypatch.setattr(bench, "SUMMARIES", summaries)
    elsewhere = f"date 2026-12-07; machine: x86_64 {other}, 2 CPU cores, Python 3.12.1"
    (summaries / "seed1-uniform.json").write_text(uniform_summary(1, elsewhere, (0.5, 0.25)))
    (summaries / "seed2-uniform.json").write_text(uniform_summary(2, here, (0.5, 0.25)))
    with pytest.raises(
        SystemExit, match=f"seed1-uniform.json ran on x86_64 {re.escape(other)} .*train other"
    ):
        bench.check_seed_pairs_here(1)
    bench.check_seed_pairs_here(2)  # this machine's kernels: its base may be built, then compared
    bench.check_seed_pairs_here(3)  # a new seed
    run_folder(tmp_path / "seed2" / "base", {}, [(0.5, 0.25)])
    bench.check_seed_pairs_here(2, tmp_path / "seed2" / "base")
    run_folder(tmp_path / "rebuilt" / "base", {}, [(0.5, 0.3)])
    with pytest.raises(SystemExit, match=r"round 0 built here \(40.0 %\) differs from the one .* \(37.5 %\)"):
        bench.check_seed_pairs_here(2, tmp_path / "rebuilt" / "base")


def test_the_benchmarks_kernels_make_mkl_take_its_intel_path_on_an_amd_cpu(monkeypatch):
    """The shim answers MKL's question "an Intel CPU?" with yes, and the benchmarks preload it on AMD CPUs only
    (kernel_reproducibility.md: with it an AMD EPYC trains the Intel Xeon's digest)."""
    import ctypes

    common = sys.modules["_common"]
    shim = common.mkl_intel_path()
    assert ctypes.CDLL(str(shim)).mkl_serv_intel_cpu_true() == 1
    kernels = common.avx2_kernels()
    assert kernels["MKL_CBWR"] == "AVX2" and kernels["ATEN_CPU_CAPABILITY"] == "avx2"
    assert (str(shim) in kernels.get("LD_PRELOAD", "")) == common.amd_cpu()
    monkeypatch.setenv("LD_PRELOAD", str(shim))
    assert "MKL's Intel path" in common.machine_line()


def test_every_committed_summary_names_the_recipe_that_runs_its_tasks():
    """A summary's `recipe` is its provenance (the reports' header names it): the recipe must run the tasks the
    summary holds. `export` refuses a run another recipe's tasks (mt10_cost's seed-2 costed_probe once named
    the hard-8 recipe)."""
    summaries = [json.loads(p.read_text()) for p in sorted(bench.RESULTS.glob("*/seed*-*.json"))]
    by_recipe: dict[str, set[tuple[str, ...]]] = {}
    for summary in summaries:
        if "recipe" in summary:  # the earliest summaries predate the field (read as `--recipe`)
            by_recipe.setdefault(summary["recipe"], set()).add(tuple(summary["tasks"]))
    assert len(by_recipe) >= 4  # MetaWorld's two recipes and Adroit's tables
    wrong = {
        recipe: sorted(tasks)
        for recipe, tasks in by_recipe.items()
        if tasks != {tuple(bench.recipe_tasks(bench.ROOT / recipe))}
    }
    assert not wrong, f"summaries whose recipe runs other tasks: {wrong}"
