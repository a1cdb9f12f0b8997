"""benchmarks/episode_levers.py: what an arm's episodes at failed states and on never-failing tasks count, and
how taking them off moves its equal-episode reading against Uniform (hand-computed curves, and the committed MT10
summaries against the report's own reading)."""

import pytest
from conftest import BENCHMARKS, load_benchmark

report = load_benchmark("efficiency_report")
levers = load_benchmark("episode_levers")  # imports the efficiency_report just loaded


def run(arm: str, success: list[float], rows: dict[str, dict]) -> "report.Run":
    """Two tasks, three expansion rounds, each task's ledger rows the same every round."""
    ledger = [
        {"round": r, "task": task, "collection_env_steps": 0, **row}
        for r in (1, 2, 3)
        for task, row in rows.items()
    ]
    return report.load_run(
        {
            "arm": arm,
            "seed": 0,
            "tasks": list(rows),
            "success": dict.fromkeys(rows, success),
            "ledger": ledger,
        }
    )


def uniform_run():
    # 2 demonstrations per task and round: 0, 2, 4, 6 episodes per task.
    return run("uniform", [0.5, 0.6, 0.7, 0.8], {t: {"demos_added": 2, "eval_episodes": 0} for t in "ab"})


def paying_run():
    # Task a: 2 demonstrations a round (1 from a fresh state, 1 at a failure) and 2 rollouts, one failed; task b:
    # 2 rollouts a round, never a failure. Per task and round (2 + 2 + 2) / 2 = 3 episodes: 0, 3, 6, 9.
    return run(
        "arm",
        [0.5, 0.7, 0.8, 0.9],
        {
            "a": {"demos_added": 2, "eval_episodes": 2, "failures": 1, "extra": {"fresh_demos": 1}},
            "b": {"demos_added": 0, "eval_episodes": 2, "failures": 0},
        },
    )


def test_episodes_at_failed_states_and_on_never_failing_tasks_per_task():
    # 3 rounds x 1 demonstration at a failure on a, 3 rounds x 2 rollouts on b; both over 2 tasks.
    assert levers.episodes_saved(paying_run()) == (1.5, 3.0)


def test_saved_episodes_move_the_reading_left_on_uniforms_curve():
    mine, uniform = paying_run(), uniform_run()
    # As run: both read at Uniform's final 6 episodes; the arm's curve there is its round 2 (80 %), Uniform's 80 %.
    assert levers.gain_at_equal_episodes(mine, uniform) == pytest.approx(0.0)
    assert levers.gain_at_equal_episodes(mine, uniform) == pytest.approx(
        report.diff_at_equal(mine, uniform, "episodes")[0]
    )
    # 3 episodes saved per task: the arm's 0, 2, 4, 6, read at 6 where it has its final 90 % against Uniform's 80 %.
    assert levers.gain_at_equal_episodes(mine, uniform, 3.0) == pytest.approx(10.0)
    # 4.5 saved: the arm ends at 4.5 episodes (90 %); Uniform's curve there is 70 + 0.25 x 10 = 72.5 %.
    assert levers.gain_at_equal_episodes(mine, uniform, 4.5) == pytest.approx(17.5)


def test_the_committed_mt10_runs_read_as_run_as_the_report_reads_them():
    runs, _ = report.load_runs(BENCHMARKS / "results" / "mt10_cost")
    seeds = sorted(s for a, s in runs if a == "costed_split" and ("uniform", s) in runs)
    assert len(seeds) >= 5
    for seed in seeds:
        mine, uniform = runs[("costed_split", seed)], runs[("uniform", seed)]
        assert levers.gain_at_equal_episodes(mine, uniform) == pytest.approx(
            report.diff_at_equal(mine, uniform, "episodes")[0]
        )
        at_failures, never_failing = levers.episodes_saved(mine)
        demos = mine.cost("demos")[-1]
        assert 0 < at_failures < demos  # most of costed_split's demonstrations come from fresh states
        assert never_failing > 0  # MT10's solved tasks are probed
