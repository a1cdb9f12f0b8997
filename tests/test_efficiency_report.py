"""The benchmark report's arithmetic (benchmarks/efficiency_report.py) on small hand-computed curves: the costs
read off interpolated curves, the paired differences and the goal verdicts the results files print."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

SPEC = importlib.util.spec_from_file_location(
    "efficiency_report", Path(__file__).parents[1] / "benchmarks" / "efficiency_report.py"
)
report = importlib.util.module_from_spec(SPEC)
sys.modules[SPEC.name] = report  # its dataclasses resolve their annotations there
SPEC.loader.exec_module(report)

TASKS = ["a", "b"]


def summary(
    arm: str, seed: int, success: list[float], frames_per_round: int, demos_per_round: int = 2
) -> dict:
    """A finished arm on two tasks with the same curve: `success` for rounds 0-3 and, per task and expansion round,
    `demos_per_round` demonstrations that cost `frames_per_round` expert frames."""
    ledger = [
        {
            "round": r,
            "task": t,
            "demos_added": demos_per_round,
            "collection_env_steps": frames_per_round,
            "eval_episodes": 10,
        }
        for r in (1, 2, 3)
        for t in TASKS
    ]
    return {
        "arm": arm,
        "seed": seed,
        "tasks": TASKS,
        "success": dict.fromkeys(TASKS, success),
        "ledger": ledger,
    }


def runs(arm_frames: int) -> dict:
    out = {}
    for seed in range(5):
        out[("uniform", seed)] = report.load_run(summary("uniform", seed, [0.5, 0.6, 0.7, 0.8], 200))
        out[("takeover", seed)] = report.load_run(summary("takeover", seed, [0.5, 0.7, 0.8, 0.9], arm_frames))
    return out


def test_cost_to_reach_interpolates_between_rounds_and_says_never():
    x, y = np.array([0.0, 4.0, 10.0]), np.array([0.5, 0.6, 0.8])
    assert report.cost_to_reach(x, y, 0.7) == pytest.approx(7.0)
    assert report.cost_to_reach(x, y, 0.4) == 0.0
    assert report.cost_to_reach(x, y, 0.9) is None


def test_compare_reads_ratios_and_equal_frames_difference():
    c = report.compare(runs(arm_frames=50), "takeover", list(range(5)))
    # Uniform's final 0.8 is reached at round 2: 100 of Uniform's 600 frames per task, 4 of its 6 demos.
    assert c.ratio["frames"] == pytest.approx([1 / 6] * 5)
    assert c.ratio["demos"] == pytest.approx([2 / 3] * 5)
    assert c.final_diff == pytest.approx([10.0] * 5)
    # At 150 frames (the arm's final): 0.9 against Uniform's 0.5 + 0.1 * 150 / 200.
    assert c.frames_diff == pytest.approx([32.5] * 5)


@pytest.mark.parametrize(("arm_frames", "verdict"), [(50, "met."), (150, "missed (0.50x, goal 0.33x).")])
def test_goal_lines_judge_the_expert_frames_goal(arm_frames, verdict):
    comparisons = {"takeover": report.compare(runs(arm_frames), "takeover", list(range(5)))}
    lines = report.goal_lines(comparisons, {"takeover"}, {})
    frames_goal = next(line for line in lines if "1/3 of Uniform's added expert frames" in line)
    assert frames_goal.endswith(verdict)


def test_per_task_frames_ratio():
    r = runs(arm_frames=150)
    assert report.task_frames_ratio(r[("takeover", 0)], r[("uniform", 0)], "b") == pytest.approx(300 / 600)
    never = report.load_run(summary("takeover", 0, [0.5, 0.55, 0.6, 0.7], 50))
    assert report.task_frames_ratio(never, r[("uniform", 0)], "a") is None
    assert report.fmt_task_ratio([0.5, None]) == "0.50x (1/2 reached)"


def test_equal_demonstrations_reads_an_arm_that_added_fewer_at_its_own_final():
    r = runs(arm_frames=50)
    fewer = report.load_run(summary("takeover", 0, [0.5, 0.7, 0.8, 0.9], 50, demos_per_round=1))
    c = report.compare({**r, ("takeover", 0): fewer}, "takeover", [0])
    # 3 demos per task: 0.9 against Uniform's 0.5 + 0.1 * 3 / 2 (its curve at 3 of its 6 demos).
    assert c.demos_diff == pytest.approx([25.0])
    assert c.final_diff == pytest.approx([10.0])


@pytest.mark.parametrize(
    ("arm_frames", "demos_per_round", "demos_verdict"),
    [(50, 2, "missed (0.67x [0.67, 0.67])."), (50, 1, "met (0.33x [0.33, 0.33]).")],
)
def test_efficiency_goal_lines(arm_frames, demos_per_round, demos_verdict):
    r = runs(arm_frames)
    for seed in range(5):
        r[("takeover", seed)] = report.load_run(
            summary("takeover", seed, [0.5, 0.7, 0.8, 0.9], arm_frames, demos_per_round)
        )
    comparisons = {"takeover": report.compare(r, "takeover", list(range(5)))}
    lines = report.efficiency_goal_lines(comparisons, {}, {"takeover": -0.4})
    assert lines[1].endswith(demos_verdict)
    assert lines[2].startswith("- At equal demonstrations") and ": met: " in lines[2]
    assert "against the reading's direction" in lines[3]


def test_predictability_table_ranks_auc_and_round0_failures_against_the_gains():
    tasks = ["a", "b", "c"]
    auc = {"a": 0.9, "b": 0.7, "c": 0.8}
    base = {"a": 0.8, "b": 0.4, "c": 0.6}  # round-0 success: failures 20, 60, 40 %
    gain = {"a": 0.02, "b": 0.10, "c": 0.05}  # the arm's round-3 gain grows with the failures, not the AUC

    def run(arm: str, seed: int) -> "report.Run":
        final = {t: base[t] + 0.1 + (gain[t] if arm == "budgeted" else 0) for t in tasks}
        return report.load_run(
            {
                "arm": arm,
                "seed": seed,
                "tasks": tasks,
                "success": {t: [base[t], base[t], base[t], final[t]] for t in tasks},
                "ledger": summary(arm, seed, [0, 0, 0, 0], 0)["ledger"],  # costs play no part here
                "predictability": {t: {"auc": auc[t]} for t in tasks},
            }
        )

    runs = {(arm, s): run(arm, s) for arm in ("uniform", "budgeted") for s in (0, 1)}
    lines, rho = report.predictability_lines(
        runs, ["uniform", "budgeted"], {"uniform": [0, 1], "budgeted": [0, 1]}, tasks, {"budgeted": "B"}
    )
    assert lines[2] == "| a | 0.90 (4) | 20 | +2 |"
    assert rho == {"budgeted": pytest.approx(-1.0)}  # AUC ranks a > c > b, gains b > c > a
    assert lines[-1].endswith("Of the round-0 failure rate and gain, over the same tasks: B +1.00.")


def test_goal_lines_count_the_seeds_where_takeover_needed_fewer_demos_and_the_seeds_missing():
    r = runs(arm_frames=50)
    for seed in range(3):
        # The initial-state arm reaches Uniform's final (0.8) at round 1, with 1 of Uniform's 6 demos per task.
        r[("initial", seed)] = report.load_run(summary("initial", seed, [0.5, 0.8, 0.9, 0.9], 50, 1))
    comparisons = {
        "takeover": report.compare(r, "takeover", [0, 1, 2]),
        "initial": report.compare(r, "initial", [0, 1, 2]),
    }
    lines = report.goal_lines(comparisons, {"takeover"}, {})
    fewer = next(line for line in lines if "fewer demonstrations than" in line)
    assert "missed, fewer on 0 of the 3 seeds both ran" in fewer
    assert "missed (3 seeds of the 5 asked)" in lines[-1]
