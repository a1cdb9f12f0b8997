"""The benchmark report's arithmetic (benchmarks/efficiency_report.py) and the cost model it shares with
adademo-report (adademo_lerobot/core/costs.py) on small hand-computed curves: the costs read off interpolated
curves, episodes and the break-even rollout cost c*, the paired differences, their t-intervals and the goal
verdicts the results files print."""

import json
import math

import numpy as np
import pytest
from conftest import load_benchmark

from adademo_lerobot.core import costs

report = load_benchmark("efficiency_report")

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
    assert c.ratio["interpolated"]["frames"].low == pytest.approx([1 / 6] * 5)
    assert c.ratio["interpolated"]["demos"].low == pytest.approx([2 / 3] * 5)
    assert c.final_diff == pytest.approx([10.0] * 5)
    # At 150 frames (the arm's final): 0.9 against Uniform's 0.5 + 0.1 * 150 / 200.
    assert c.frames_diff == pytest.approx([32.5] * 5)


@pytest.mark.parametrize(
    ("arm_frames", "verdict"),
    [
        (50, "interpolated met (0.17x [0.17, 0.17], goal 0.33x)"),
        (150, "interpolated missed by 0.17x (0.50x [0.50, 0.50], goal 0.33x)"),
    ],
)
def test_goal_lines_judge_the_expert_frames_goal(arm_frames, verdict):
    comparisons = {"takeover": report.compare(runs(arm_frames), "takeover", list(range(5)))}
    lines = report.goal_lines(comparisons, {"takeover"}, {})
    frames_goal = next(line for line in lines if "1/3 of Uniform's added expert frames" in line)
    assert f": {verdict}; at trained policies" in frames_goal


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
    [(50, 2, "missed by 0.33x (0.67x [0.67, 0.67])"), (50, 1, "met (0.33x [0.33, 0.33])")],
)
def test_efficiency_goal_lines(arm_frames, demos_per_round, demos_verdict):
    r = runs(arm_frames)
    for seed in range(5):
        r[("takeover", seed)] = report.load_run(
            summary("takeover", seed, [0.5, 0.7, 0.8, 0.9], arm_frames, demos_per_round)
        )
    comparisons = {"takeover": report.compare(r, "takeover", list(range(5)))}
    lines = report.efficiency_goal_lines(comparisons, {}, {"takeover": -0.4})
    assert f"demonstrations: interpolated {demos_verdict}; at trained policies" in lines[1]
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


# The cost model: episodes and the break-even rollout cost c*.
STEP_LIMIT = 100


def costed(
    arm: str, seed: int, success: list[float], demos: int, rollouts: int, failed: int = 0, tasks=TASKS
) -> dict:
    """A finished arm whose every task and round added `demos` demonstrations of 50 frames, `failed` failed
    expert attempts (each the whole step limit) and `rollouts` policy rollouts: `demos + failed` expert
    episodes."""
    ledger = [
        {
            "round": r,
            "task": t,
            "demos_added": demos,
            "demo_frames": 50 * demos,
            "collection_env_steps": 50 * demos + STEP_LIMIT * failed,
            "expert_failures": 0,
            "eval_episodes": rollouts,
            "eval_episodes_run": rollouts,
        }
        for r in (1, 2, 3)
        for t in tasks
    ]
    return {
        "arm": arm,
        "seed": seed,
        "tasks": tasks,
        "settings": {"suite": {"max_episode_steps": STEP_LIMIT}, "demo_start": "initial"},
        "success": dict.fromkeys(tasks, success),
        "ledger": ledger,
    }


def cost_runs(arm_rollouts: list[int], arm_success=(0.5, 0.7, 0.9, 0.9)) -> dict:
    """Uniform: 2 demos + 1 failed attempt per task and round (9 expert episodes per task to its final 0.8).
    The arm: 1 demo and `arm_rollouts[seed]` rollouts per task and round, crossing 0.8 halfway through round
    2."""
    out = {}
    for seed, rollouts in enumerate(arm_rollouts):
        out[("uniform", seed)] = report.load_run(
            costed("uniform", seed, [0.5, 0.6, 0.7, 0.8], 2, 0, failed=1)
        )
        out[("arm", seed)] = report.load_run(costed("arm", seed, list(arm_success), 1, rollouts))
    return out


def test_expert_episodes_count_every_attempt_but_a_takeover_requests_first():
    # Initial states: 3 demonstrations and 2 failed attempts (each the step limit) are 5 episodes.
    row = {"demos_added": 3, "demo_frames": 150, "collection_env_steps": 150 + 200, "expert_failures": 0}
    assert costs.failed_attempts(row, STEP_LIMIT) == (2, 2)
    assert costs.expert_episodes(row, STEP_LIMIT) == (5, 5)
    # Takeover: 3 corrections (inside their rollouts), 2 failed takeover attempts (inside theirs too), then
    # from the initial state one demonstration at once and one after a failed attempt: 3 expert episodes.
    takeover = {
        "demos_added": 5,
        "corrections": 3,
        "takeover_failures": 2,
        "demo_frames": 250,
        "collection_env_steps": 250 + 3 * STEP_LIMIT,
        "expert_failures": 0,
    }
    assert costs.expert_episodes(takeover, STEP_LIMIT, takeover=True) == (3, 3)
    # The first protocol recorded no takeover failures: its expert failure was one, or from an initial state.
    first = {**takeover, "demos_added": 4, "corrections": 4, "expert_failures": 1, "demo_frames": 200}
    del first["takeover_failures"]
    first["collection_env_steps"] = 200 + 5 * STEP_LIMIT
    assert costs.expert_episodes(first, STEP_LIMIT, takeover=True) == (4, 5)
    # No frames kept recorded: each demonstration took 1..100 steps, so 350 steps hold 1..3 failed attempts.
    bare = {"demos_added": 3, "collection_env_steps": 350, "expert_failures": 0}
    assert costs.failed_attempts(bare, STEP_LIMIT) == (1, 3)
    assert costs.expert_episodes(bare, STEP_LIMIT) == (4, 6)
    assert costs.rollouts({"eval_episodes": 7, "eval_episodes_run": 9}) == 9


def test_break_even_cost_read_interpolated_and_at_trained_policies():
    r = cost_runs([10] * 5)
    assert r[("uniform", 0)].cost("expert_episodes")[-1] == pytest.approx(9)
    assert r[("arm", 0)].cost("episodes") == pytest.approx([0, 11, 22, 33])
    c = report.compare(r, "arm", list(range(5)))
    # Interpolated: halfway through round 2, 1.5 expert episodes and 15 rollouts: (9 - 1.5) / 15.
    assert c.cstar["interpolated"].low == pytest.approx([0.5] * 5)
    # At trained policies: round 2's policy, 2 expert episodes and 20 rollouts: (9 - 2) / 20.
    assert c.cstar["trained"].low == pytest.approx([0.35] * 5)
    assert c.cstar["trained"].exact
    # Episodes to reach Uniform's final over Uniform's 9: 16.5 / 9 interpolated, 22 / 9 at trained policies.
    assert c.ratio["interpolated"]["episodes"].low == pytest.approx([16.5 / 9] * 5)
    assert c.ratio["trained"]["episodes"].low == pytest.approx([22 / 9] * 5)
    # At equal episodes: both at Uniform's final 9; the arm's curve there 0.5 + 0.2 * 9 / 11, Uniform's 0.8.
    assert c.episodes_diff.low == pytest.approx([100 * (0.5 + 0.2 * 9 / 11 - 0.8)] * 5)
    assert c.episodes_level.low == pytest.approx([9] * 5)


def test_break_even_cost_infinite_never_and_negative():
    assert costs.break_even(3, 0, 9) == math.inf
    assert costs.break_even(12, 0, 9) == -math.inf
    assert costs.break_even(12, 10, 9) == pytest.approx(-0.3)
    never = report.compare(cost_runs([10] * 2, arm_success=(0.5, 0.6, 0.7, 0.75)), "arm", [0, 1])
    assert never.cstar["interpolated"].low == [None, None]
    assert report.fmt_cstar(never.cstar["interpolated"]) == "never reaches Uniform's final on 2 seeds"
    values = report.PerSeed([0.5, math.inf, -math.inf, None], [0.5, math.inf, -math.inf, None])
    assert report.fmt_cstar(values) == (
        "0.50 over 1 seed; pays off at any rollout cost on 1 seed; does not pay off even with free rollouts "
        "on 1 seed; never reaches Uniform's final on 1 seed"
    )
    negative = report.PerSeed([-0.2, -0.4], [-0.2, -0.4])
    assert report.fmt_cstar(negative).endswith("(negative: does not pay off even with free rollouts)")


def test_cost_ratios_and_break_even_get_t_intervals_over_seeds():
    # Rollouts 5..25 per task and round: c* interpolated (9 - 1.5) / (1.5 R) per seed.
    rollouts = [5, 10, 15, 20, 25]
    c = report.compare(cost_runs(rollouts), "arm", list(range(5)))
    values = np.array([7.5 / (1.5 * n) for n in rollouts])
    half = 2.776 * values.std(ddof=1) / np.sqrt(5)  # Student's t, 4 degrees of freedom
    mean = values.mean()
    assert report.fmt_cstar(c.cstar["interpolated"]) == f"{mean:.2f} [{mean - half:.2f}, {mean + half:.2f}]"
    # A ratio's interval is a t-interval too (a percentile bootstrap over 5 seeds is narrower: ~0.18..0.42).
    ratios = report.PerSeed([0.1, 0.2, 0.3, 0.4, 0.5], [0.1, 0.2, 0.3, 0.4, 0.5])
    assert report.fmt_ratio(ratios) == "0.30x [0.10, 0.50]"
    ratios = report.PerSeed([0.1, None, 0.3], [0.1, None, 0.3])
    assert report.fmt_ratio(ratios) == "0.20x [-1.07, 1.47]; not reached on 1 seed"


def test_figures_on_expert_episodes_known_within_bounds_are_ranges():
    r = cost_runs([10] * 2)
    for seed in (
        0,
        1,
    ):  # Uniform's summaries without the frames kept: 1..3 failed attempts per task and round
        summary = costed("uniform", seed, [0.5, 0.6, 0.7, 0.8], 2, 0, failed=1)
        for row in summary["ledger"]:
            del row["demo_frames"]
        r[("uniform", seed)] = report.load_run(summary)
    uniform = r[("uniform", 0)]
    assert not uniform.exact
    # 200 steps per task and round: 2 demos of 1..100 steps, so 0..1 failed attempts: 6..9 expert episodes.
    assert uniform.cost("expert_episodes")[-1] == pytest.approx(6)
    assert uniform.cost("expert_episodes", high=True)[-1] == pytest.approx(9)
    c = report.compare(r, "arm", [0, 1])
    assert c.cstar["interpolated"].low == pytest.approx([(6 - 1.5) / 15] * 2)
    assert c.cstar["interpolated"].high == pytest.approx([(9 - 1.5) / 15] * 2)
    assert report.fmt_cstar(c.cstar["interpolated"]) == "0.30 [0.30, 0.30] to 0.50 [0.50, 0.50]"
    assert (
        report.cstar_verdict(c.cstar["interpolated"], 0.4)
        == "not decided within the bounds of expert episodes"
    )


def test_cost_goal_lines_say_by_how_much_a_goal_is_missed():
    comparisons = {"arm": report.compare(cost_runs([10] * 5), "arm", list(range(5)))}
    lines = report.cost_goal_lines(comparisons, {"arm": "A"})
    assert lines[0] == "Best arm by c*: A (5 seeds)."
    assert (
        "95 % intervals: missed: interpolated, c* 0.50 [0.50, 0.50] (missed by 0.50; 1.83x [1.83, 1.83] "
        "Uniform's episodes)" in lines[1]
    )
    assert "at trained policies, c* 0.35 [0.35, 0.35] (missed by 0.65;" in lines[1]
    # Uniform's final with 1.5 of its 6 demos interpolated, 2 at trained policies.
    assert "0.25x [0.25, 0.25] of its demonstrations (met)" in lines[1]
    assert "0.33x [0.33, 0.33] of its demonstrations (met)." in lines[1]
    gap = 100 * (0.5 + 0.2 * 9 / 11 - 0.8)
    assert lines[3] == (
        "- At equal episodes >= Uniform + 3 points after 3 rounds, 95 % interval above 0: missed by "
        f"{3 - gap:.1f} points (the interval is not above 0): {gap:+.1f} [{gap:+.1f}, {gap:+.1f}]."
    )
    cheap = {"arm": report.compare(cost_runs([1] * 5), "arm", list(range(5)))}  # (9 - 1.5) / 1.5 = 5
    line = report.cost_goal_lines(cheap, {"arm": "A"})[1]
    # And (9 - 2) / 2 = 3.5 at trained policies: both readings meet both halves of the goal.
    assert "95 % intervals: met: interpolated, c* 5.00 [5.00, 5.00] (met;" in line
    assert "at trained policies, c* 3.50 [3.50, 3.50] (met;" in line


def test_goals_are_not_read_on_a_seed_where_uniform_ends_at_or_under_round_0():
    r = runs(50)
    r[("uniform", 2)] = report.load_run(
        summary("uniform", 2, [0.5, 0.6, 0.4, 0.5], 200)
    )  # ends where it began
    comparisons = {"takeover": report.compare(r, "takeover", list(range(5)))}
    assert comparisons["takeover"].flat_seeds == [2]
    assert comparisons["takeover"].ratio["interpolated"]["demos"].low[2] == 0.0  # reached before adding any
    not_read = "not read: on 1 of 5 seeds Uniform's final average is at or under round 0's"
    assert f"demonstrations: interpolated {not_read}" in report.efficiency_goal_lines(comparisons, {}, {})[1]
    cost = report.cost_goal_lines(comparisons, {})[1]
    assert "intervals: missed:" in cost and not_read in cost
    lines = report.flat_uniform_lines(r, list(range(5)))
    assert "did not raise its average on 1 of 5 seeds (seed 2 50.0 -> 50.0 %)" in lines[1]
    assert report.flat_uniform_lines(runs(50), list(range(5))) == []  # Uniform gained on every seed
    assert (
        "not read"
        not in report.efficiency_goal_lines(
            {"takeover": report.compare(runs(50), "takeover", list(range(5)))}, {}, {}
        )[1]
    )


def test_points_goal_is_met_only_with_the_interval_above_zero():
    assert report.points_goal_line("episodes", np.array([4.0, 5.0, 6.0]), goal=3, min_seeds=0).endswith(
        ": met: +5.0 [+2.5, +7.5]."
    )
    wide = report.points_goal_line("episodes", np.array([-4.0, 5.0, 14.0]), goal=3, min_seeds=0)
    assert ": missed (the interval is not above 0): +5.0 [-17.4, +27.4]." in wide


def test_principle_b_alone_is_budgeted_minus_task_only_paired_by_seed():
    runs = {}
    for seed in (0, 1, 2):
        # Both add 1 demo per task and round; budgeted (A + B) gains more per round and runs more rollouts.
        runs[("budgeted", seed)] = report.load_run(costed("budgeted", seed, [0.5, 0.7, 0.8, 0.9], 1, 10))
        runs[("task_only", seed)] = report.load_run(
            costed("task_only", seed, [0.5, 0.6, 0.7, 0.7 + 0.05 * seed], 1, 5)
        )
    seeds_of = {"budgeted": [0, 1, 2], "task_only": [0, 1, 2]}
    line = report.principle_b_line(runs, seeds_of, {})
    demos = np.array([100 * (0.9 - (0.7 + 0.05 * s)) for s in (0, 1, 2)])
    half = 4.303 * demos.std(ddof=1) / np.sqrt(3)
    # At equal episodes: task_only's final 18 episodes per task; budgeted's curve there 0.7 + 0.1 * 7 / 11.
    episodes = np.array([100 * (0.7 + 0.1 * 7 / 11 - (0.7 + 0.05 * s)) for s in (0, 1, 2)])
    half_e = 4.303 * episodes.std(ddof=1) / np.sqrt(3)
    assert line == (
        "- Principle B on its own, A + B minus A (budgeted minus task_only), paired over 3 seeds (no target: "
        f"measured): at equal demonstrations {demos.mean():+.1f} [{demos.mean() - half:+.1f}, "
        f"{demos.mean() + half:+.1f}] points, at equal episodes {episodes.mean():+.1f} "
        f"[{episodes.mean() - half_e:+.1f}, {episodes.mean() + half_e:+.1f}] points."
    )
    assert "not measured (no summaries of task_only)" in report.principle_b_line(runs, {"budgeted": [0]}, {})


def test_break_even_words_for_one_run_against_a_uniform_run():
    uniform = {"success": [0.5, 0.8], "expert": [0, 90], "expert_high": [0, 90], "rollouts": [0, 0]}
    run = {
        "success": [0.5, 0.7, 0.9],
        "expert": [0, 10, 20],
        "expert_high": [0, 10, 20],
        "rollouts": [0, 100, 200],
    }
    lines = costs.break_even_lines(run, uniform)
    assert lines[0] == (
        "On this run AdaDemo pays off if a policy rollout costs less than 0.35 of an expert episode (it "
        "reached the Uniform run's final 80.0 % with round 2's policy, after 20 expert episodes and 200 "
        "rollouts; Uniform used 90 expert episodes)."
    )
    assert "c* is 0.50 (after 15 expert episodes and 150.0 rollouts)" in lines[1]
    dear = {**run, "expert": [0, 100, 200], "expert_high": [0, 100, 200]}
    assert "does not pay off even with free rollouts" in costs.break_even_lines(dear, uniform)[0]
    free = {**run, "rollouts": [0, 0, 0]}
    assert "pays off whatever a policy rollout costs" in costs.break_even_lines(free, uniform)[0]
    short = {**run, "success": [0.5, 0.6, 0.7]}
    assert costs.break_even_lines(short, uniform) == [
        "This run never reached the Uniform run's final 80.0 % (its best: 70.0 % after round 2): no "
        "break-even rollout cost (Uniform used 90 expert episodes)."
    ]
    flat = {**uniform, "success": [0.5, 0.45]}  # Uniform's added demonstrations lowered its average
    assert costs.break_even_lines(run, flat) == [
        "The Uniform run's final 45.0 % is no higher than where this run started (50.0 % at round 0): it is "
        "reached with nothing added, so it says nothing of a break-even rollout cost (Uniform used 90 expert "
        "episodes)."
    ]


def test_runs_whose_round_0_differs_from_uniforms_are_left_out_of_the_pairing(tmp_path):
    """A run trained on another CPU type starts from another policy: pairing it would compare machines."""
    for arm, seed, round0 in [
        ("uniform", 0, 0.5),
        ("budgeted", 0, 0.5),
        ("uniform", 1, 0.5),
        ("budgeted", 1, 0.52),
    ]:
        path = tmp_path / f"seed{seed}-{arm}.json"
        path.write_text(json.dumps(summary(arm, seed, [round0, 0.6, 0.7, 0.8], 200)))
    runs, unpaired = report.load_runs(tmp_path)
    assert unpaired == [("budgeted", 1)]
    assert sorted(runs) == [("budgeted", 0), ("uniform", 0), ("uniform", 1)]


def test_kept_successful_rollouts_are_reported_per_task_only_where_an_arm_kept_some():
    kept = summary("keep", 0, [0.5, 0.6, 0.7, 0.8], 200)
    for row in kept["ledger"]:
        row["policy_episodes_kept"] = 3 if row["task"] == "a" else 1
    runs = {("uniform", 0): report.load_run(summary("uniform", 0, [0.5, 0.6, 0.7, 0.8], 200))}
    assert report.kept_rollout_lines(runs, {"uniform": [0]}, {}) == []
    runs[("keep", 0)] = report.load_run(kept)
    [_, line] = report.kept_rollout_lines(runs, {"uniform": [0], "keep": [0]}, {"keep": "Keeper"})
    assert line.endswith("Keeper 6.0.")  # (3 + 1) x 3 rounds over 2 tasks


def test_where_the_episodes_went_per_task_mean_over_paired_seeds():
    runs = {}
    for seed, (demos_a, evals) in enumerate([(2, 10), (4, 20)]):
        arm = summary("arm", seed, [0.5, 0.6, 0.7, 0.8], 200)
        for row in arm["ledger"]:
            row["demos_added"] = demos_a if row["task"] == "a" else 0
            row["eval_episodes"] = evals
        runs[("arm", seed)] = report.load_run(arm)
        uniform = summary("uniform", seed, [0.5, 0.6, 0.7, 0.8], 200, 6)
        for row in uniform["ledger"]:
            row["eval_episodes"] = 0
        runs[("uniform", seed)] = report.load_run(uniform)
    runs[("arm", 2)] = runs[("arm", 0)]  # a seed Uniform did not finish: not in the mean
    lines = report.where_episodes_went(
        runs, ["uniform", "arm"], {"uniform": [0, 1], "arm": [0, 1, 2]}, TASKS, {}
    )
    assert lines[-1].splitlines()[2:] == [
        "| a | 18.0 / 0.0 | 9.0 / 45.0 |",  # 3 rounds of (2 + 4) / 2 demonstrations, of (10 + 20) / 2 rollouts
        "| b | 18.0 / 0.0 | 0.0 / 45.0 |",
    ]


def demos_run(arm: str, curves: dict[str, list[float]], demos: dict[str, int]) -> "report.Run":
    """Seed 0 of `arm`: success `curves` per task over rounds 0-3, `demos[task]` demonstrations in each of rounds
    1-3 (no other cost)."""
    ledger = [
        {"round": r, "task": t, "demos_added": demos[t], "collection_env_steps": 0, "eval_episodes": 0}
        for r in (1, 2, 3)
        for t in curves
    ]
    return report.load_run(
        {"arm": arm, "seed": 0, "tasks": list(curves), "success": curves, "ledger": ledger}
    )


def test_demonstration_return_says_where_an_allocation_bought_nothing():
    tasks = ["a", "b", "c"]
    # Round 0 -> last: a solved (100 -> 100 %), b raised (40 -> 70 %), c failing and not raised (10 -> 5 %).
    curves = {"a": [1.0, 1.0, 1.0, 1.0], "b": [0.4, 0.5, 0.6, 0.7], "c": [0.1, 0.1, 0.1, 0.05]}
    runs = {
        ("uniform", 0): demos_run("uniform", curves, dict.fromkeys(tasks, 2)),
        ("adademo", 0): demos_run("adademo", curves, {"a": 0, "b": 2, "c": 4}),
    }
    lines = report.demonstration_return_lines(
        runs, ["uniform", "adademo"], {"uniform": [0], "adademo": [0]}, {"adademo": "A"}
    )
    table_rows = lines[4].splitlines()[2:]
    # Uniform's return: (last - round 0) per 10 of its 6 demonstrations per task, in points.
    assert table_rows == [
        "| a | 100 -> 100 | +0.0 | 0.00x |",
        "| b | 40 -> 70 | +50.0 | 1.00x |",
        "| c | 10 -> 5 | -8.3 | 2.00x |",
    ]
    assert lines[-1] == (
        "Share of the added demonstrations that went to tasks Uniform's demonstrations did not raise: "
        "solved at round 0 (>= 95 %) (a): uniform 33 %, A 0 %; still failing (c): uniform 33 %, A 67 %."
    )


def test_goal_lines_of_an_arm_that_never_reaches_uniforms_final_say_so_once():
    r = runs(50)
    r[("takeover", 0)] = report.load_run(summary("takeover", 0, [0.5, 0.6, 0.6, 0.7], 50))
    comparisons = {"takeover": report.compare(r, "takeover", [0])}
    [_, demos_line, *_] = report.efficiency_goal_lines(comparisons, {}, {})
    assert demos_line == (
        "- Uniform's final average with <= 1/3 of Uniform's added demonstrations: interpolated missed: never "
        "reached on 1 of 1 seeds; at trained policies missed: never reached on 1 of 1 seeds."
    )
    cost_line = report.cost_goal_lines(comparisons, {})[1]
    assert cost_line.endswith(
        "95 % intervals: missed: interpolated, never reaches Uniform's final (1 seed); at trained policies, "
        "never reaches Uniform's final (1 seed)."
    )


def test_demonstration_return_of_a_task_uniform_added_nothing_to_is_left_blank(recwarn):
    curves = {"a": [0.1, 0.1, 0.1, 0.1], "b": [0.4, 0.5, 0.6, 0.7]}
    runs = {
        ("uniform", 0): demos_run("uniform", curves, {"a": 0, "b": 2}),
        ("arm", 0): demos_run("arm", curves, {"a": 1, "b": 2}),
    }
    lines = report.demonstration_return_lines(runs, ["uniform", "arm"], {"uniform": [0], "arm": [0]}, {})
    # The expert failed every attempt on a for Uniform: no return there, so a is not counted as 'not raised'.
    assert lines[4].splitlines()[2:] == ["| a | 10 -> 10 | - | - |", "| b | 40 -> 70 | +50.0 | 1.00x |"]
    assert lines[-1] == "Uniform's demonstrations raised every task they were added to (return above 0)."
    assert not recwarn.list
