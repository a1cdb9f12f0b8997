"""benchmarks/data_efficiency.py status: where each run folder of a days-long table stands, read from the files
adademo-run leaves (its run state and each round's evaluation summary)."""

import json
import re
import sys

import pytest
from conftest import load_benchmark

bench = load_benchmark("data_efficiency")


def run_folder(root, done, rates_by_round):
    """A run folder's run state and evaluation summaries, in the shape adademo-run writes them."""
    root.mkdir(parents=True)
    (root / "run_state.json").write_text(json.dumps({"settings": {}, "done": done}))
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
