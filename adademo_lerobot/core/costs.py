"""What the expansion rounds cost a person at a real robot, and when adaptive collection pays off.

On a robot every episode needs a person to reset the scene. An *episode* is

- every expert attempt that starts an episode of its own: a demonstration or a failed attempt from an
  initial state (a fresh one, or a failed rollout's), and a retry from a takeover state;
- every policy rollout an expansion round ran (the ledger's `eval_episodes_run`).

A correction (`--demo_start=takeover`) continues the failed rollout it corrects: the rollout and the expert's
first attempt from the takeover state are ONE episode (the rollout). If that attempt fails and the expert
starts again from the initial state (`--takeover.fallback=initial`), each attempt from there is one more
episode. The fixed evaluation set after each round is free (every arm runs the same one).

From one ledger row (a task in a round), with L the step limit:

    rollouts          R = eval_episodes_run
    failed attempts   F = (collection_env_steps - demo_frames) / L
                          (a failed attempt never succeeds, so the simulated experts run it to the step
                          limit; a correction gets the whole limit from its takeover state too)
    takeover requests T = corrections + takeover_failures   (one per failed rollout the expert took over)
    expert episodes   X = demos_added + F - T                (every attempt but each request's first)
    episodes            = X + R

Where a row does not record these exactly (no `demo_frames`, a remainder, no `takeover_failures`), X is given
as the closest bounds the row allows (`expert_episodes` returns (low, high)).

The break-even rollout cost c* (in expert episodes per rollout): with X expert episodes and R rollouts spent
when an arm first reaches Uniform's final average, and X_U Uniform's expert episodes to its final, the arm
costs no more than Uniform while a rollout costs at most c* = (X_U - X) / R of an expert episode; infinite
when R = 0 and X <= X_U; negative when the arm does not pay off even with free rollouts. Read at the first
round whose trained policy reaches the target, or interpolated linearly inside the round where the curve
crosses it.
"""

from __future__ import annotations

import math


def rollouts(row: dict) -> int:
    """Policy episodes the round ran on the task (every one, past any stopping point too)."""
    return int(row.get("eval_episodes_run", row.get("eval_episodes", 0)))


def failed_attempts(row: dict, step_limit: int | None, demo_frames: int | None = None) -> tuple[int, int]:
    """Expert attempts that kept nothing, (low, high): exact (low == high) when the row records the frames
    kept (or `demo_frames` gives them) and the rest is whole step limits; else the bounds the row allows."""
    steps, demos = int(row["collection_env_steps"]), int(row["demos_added"])
    floor = int(row.get("expert_failures", 0))  # each expert failure is at least one failed attempt
    frames = row.get("demo_frames", demo_frames)
    if frames is not None:
        wasted = steps - int(frames)
        if step_limit and wasted % step_limit == 0:
            return wasted // step_limit, wasted // step_limit
        # Attempts shorter than the limit after all: each took between 1 and `step_limit` steps.
        low = -(-wasted // step_limit) if step_limit else min(wasted, 1)
        return max(floor, low), max(floor, wasted)
    if step_limit:  # frames kept unknown: each kept demonstration took between 1 and `step_limit` steps
        low = -(-(steps - demos * step_limit) // step_limit)
        return max(floor, low), max(floor, (steps - demos) // step_limit)
    return floor, max(floor, steps - demos)


def takeover_requests(row: dict, takeover: bool) -> tuple[int, int]:
    """Failed rollouts the expert took over (the first attempt there is inside the rollout's episode), (low,
    high). Rows from before `takeover_failures` was recorded (the first protocol, no fallback) say only that
    each expert failure was one, or a failure from an initial state."""
    corrections = int(row.get("corrections", 0))
    if "takeover_failures" in row:
        return corrections + int(row["takeover_failures"]), corrections + int(row["takeover_failures"])
    if takeover:
        return corrections, corrections + int(row.get("expert_failures", 0))
    return corrections, corrections


def expert_episodes(
    row: dict, step_limit: int | None, takeover: bool = False, demo_frames: int | None = None
) -> tuple[int, int]:
    """Expert episodes of one ledger row, (low, high): every expert attempt but each takeover request's
    first."""
    f_low, f_high = failed_attempts(row, step_limit, demo_frames)
    t_low, t_high = takeover_requests(row, takeover)
    demos = int(row["demos_added"])
    from_initial = demos - int(row.get("corrections", 0))  # at least the demonstrations from initial states
    return max(from_initial, demos + f_low - t_high), max(from_initial, demos + f_high - t_low)


def crossing(success, target: float, trained_only: bool = False) -> tuple[int, float] | None:
    """Where a success curve (by round) first reaches `target`: (round k, the fraction f of the way from
    round k - 1 to round k, linearly). Trained only: the first round whose policy reaches it (f = 1). None:
    never."""
    for k, value in enumerate(success):
        if value >= target:
            if k == 0 or trained_only:
                return k, 1.0
            return k, float((target - success[k - 1]) / (value - success[k - 1]))
    return None


def read(cost, at: tuple[int, float]) -> float:
    """A cumulative cost curve (by round) at a `crossing`."""
    k, f = at
    return float(cost[k]) if k == 0 else float(cost[k - 1] + f * (cost[k] - cost[k - 1]))


def break_even(expert: float, rollouts_spent: float, uniform_expert: float) -> float:
    """c* = (X_U - X) / R; infinite when no rollout was spent and X <= X_U, minus infinite when X > X_U."""
    if rollouts_spent == 0:
        return math.inf if expert <= uniform_expert else -math.inf
    return (uniform_expert - expert) / rollouts_spent


def break_even_words(c: float) -> str:
    """c* in words, for a sentence that goes on with what the run spent."""
    if c == math.inf:
        return "pays off whatever a policy rollout costs"
    if c < 0:
        return "does not pay off even with free rollouts"
    if c == 0:
        return "breaks even only if policy rollouts are free"
    return f"pays off if a policy rollout costs less than {c:.2f} of an expert episode"


def _count(low: float, high: float) -> str:
    return f"{low:.0f}" if round(low) == round(high) else f"{low:.0f}-{high:.0f}"


def _cstar(low: float, high: float) -> str:
    def one(c: float) -> str:
        return {math.inf: "infinite", -math.inf: "minus infinite"}.get(c, f"{c:.2f}")

    return one(low) if one(low) == one(high) else f"between {one(low)} and {one(high)}"


def break_even_lines(run: dict, uniform: dict, label: str = "AdaDemo") -> list[str]:
    """c* in plain words for one run against a Uniform run on the same tasks. Each dict: `success` (average by
    round), and totals over tasks added by the expansion rounds up to each round: `expert` and `expert_high`
    (expert episodes at their lower and upper bound), `rollouts`."""
    target = uniform["success"][-1]
    uniform_low, uniform_high = uniform["expert"][-1], uniform["expert_high"][-1]
    used = f"Uniform used {_count(uniform_low, uniform_high)} expert episodes"
    at = crossing(run["success"], target, trained_only=True)
    if at is None:
        best = max(range(len(run["success"])), key=lambda k: run["success"][k])
        return [
            f"This run never reached the Uniform run's final {100 * target:.1f} % (its best: "
            f"{100 * run['success'][best]:.1f} % after round {best}): no break-even rollout cost ({used})."
        ]
    if at[0] == 0:  # Uniform's added data did not lift it above where both runs started
        return [
            f"The Uniform run's final {100 * target:.1f} % is no higher than where this run started "
            f"({100 * run['success'][0]:.1f} % at round 0): it is reached with nothing added, so it says nothing "
            f"of a break-even rollout cost ({used})."
        ]

    def reading(at: tuple[int, float]) -> tuple[float, float, str, float]:
        """c* at its lower and upper bound, the expert episodes and the rollouts spent at `at`."""
        low, high, spent = read(run["expert"], at), read(run["expert_high"], at), read(run["rollouts"], at)
        return (
            break_even(high, spent, uniform_low),
            break_even(low, spent, uniform_high),
            _count(low, high),
            spent,
        )

    c_low, c_high, expert, spent = reading(at)
    words = (
        break_even_words(c_low)
        if c_low == c_high
        else f"breaks even at a rollout cost {_cstar(c_low, c_high)} expert episodes (known within bounds)"
    )
    lines = [
        f"On this run {label} {words} (it reached the Uniform run's final {100 * target:.1f} % with round "
        f"{at[0]}'s policy, after {expert} expert episodes and {spent:.0f} rollouts; {used})."
    ]
    between = crossing(run["success"], target)
    if between[0] > 0:  # the curve crosses the target inside that round: read linearly, as the benchmark does
        c_low, c_high, expert, spent = reading(between)
        lines.append(
            f"Read between rounds (linearly inside round {between[0]}, as the benchmark reports do): c* is "
            f"{_cstar(c_low, c_high)} (after {expert} expert episodes and {spent:.1f} rollouts)."
        )
    lines.append(
        "An expert episode: a demonstration or a failed expert attempt, each a scene reset; a correction "
        "from the point of failure is part of the rollout it corrects; the fixed evaluation set is not "
        "counted."
    )
    return lines
