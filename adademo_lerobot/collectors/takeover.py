"""Corrections from the point of failure: where, on a failed policy rollout, the expert takes over.

With `--demo_start=takeover` a demonstration no longer starts from the failed episode's initial state (the
paper's principle B) but from a state on the policy's own failed rollout, so its frames teach what the policy got
wrong rather than what it already does (reaching, approaching), on the states the policy actually visits (as
HG-DAgger and LeRobot's DAgger-style `lerobot-rollout` collect). Two rules pick the step:

- `disagreement`: the first step where the policy's action and the expert's action at the same state (what the
  expert would do, taking over there) differ by more than `threshold` (Euclidean distance between the two
  actions in the env's [-1, 1] action box) for `consecutive` steps in a row, moved `backoff` steps earlier; a
  failed rollout on which they never disagree that long falls back to the `backoff` rule;
- `backoff`: `backoff` steps before the rollout stalled (the first step from which its observation stays within
  `stall_tolerance` of the final one), or before its end if it never stalled.

The evaluation keeps the whole simulator state at every step (`get_state()`), so the correction starts from
exactly that state, and the dataset records it (`adademo/start_state`) so that it replays exactly.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from adademo_lerobot.core.episodes import RolloutTrace
from adademo_lerobot.core.errors import AdaDemoError

DEMO_STARTS = ("initial", "takeover")
TAKEOVER_RULES = ("disagreement", "backoff")
FALLBACKS = ("initial", "none")


@dataclass
class TakeoverArgs:
    # disagreement | backoff (see `adademo_lerobot/collectors/takeover.py`).
    rule: str = "disagreement"
    # disagreement: the distance between the policy's and the expert's action that counts as disagreeing
    # (a policy that follows the expert stays under ~1.2 on MetaWorld; a wrong turn or grip is ~2:
    # benchmarks/results/takeover_pilot.md).
    threshold: float = 1.5
    # disagreement: steps in a row that must disagree.
    consecutive: int = 5
    # Steps before the point found (the disagreement, the stall or the end) where the expert takes over.
    backoff: int = 10
    # backoff: the rollout has stalled once its observation stays within this distance of the final one.
    stall_tolerance: float = 0.01
    # Expert attempts from the takeover state (a retry from the same bad state rarely succeeds: 1 of 13 in
    # benchmarks/results/takeover_pilot.md, each failure costing a whole step limit of expert frames).
    attempts: int = 1
    # When every attempt fails: `initial`: the expert demonstrates from the failed episode's initial state instead
    # (the paper's answer to the failure); `none`: the failure gets no demonstration.
    fallback: str = "initial"

    def validate(self) -> None:
        if self.rule not in TAKEOVER_RULES:
            raise AdaDemoError(
                f"unknown --takeover.rule={self.rule!r}; choose one of {', '.join(TAKEOVER_RULES)}"
            )
        for name in ("threshold", "backoff", "stall_tolerance"):
            if getattr(self, name) < 0:
                raise AdaDemoError(f"--takeover.{name} must be >= 0, got {getattr(self, name)}")
        if self.consecutive < 1:
            raise AdaDemoError(f"--takeover.consecutive must be >= 1, got {self.consecutive}")
        if self.attempts < 1:
            raise AdaDemoError(f"--takeover.attempts must be >= 1, got {self.attempts}")
        if self.fallback not in FALLBACKS:
            raise AdaDemoError(
                f"unknown --takeover.fallback={self.fallback!r}; choose one of {', '.join(FALLBACKS)}"
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def check_demo_start(demo_start: str, takeover: TakeoverArgs) -> None:
    if demo_start not in DEMO_STARTS:
        raise AdaDemoError(f"unknown --demo_start={demo_start!r}; choose one of {', '.join(DEMO_STARTS)}")
    takeover.validate()


def check_can_take_over(suite, collector_config) -> None:
    """Corrections need the suite to restore the whole state at any step and an expert that acts from any state."""
    if not suite.restores_any_state:
        raise AdaDemoError(
            f"--demo_start=takeover: the {suite.name} suite restores initial states by reset seed only, not the "
            "whole state at any step; corrections need a suite that does (metaworld, fetch, adroit)"
        )
    collector_config.check_acts_mid_episode(suite)


@dataclass
class TakeoverPoint:
    """Where the expert takes over a failed rollout: the step, the whole state there and the rule that chose it."""

    step: int
    state: np.ndarray
    rule: str


def stall_step(observations: np.ndarray, tolerance: float) -> int:
    """The first step from which every observation stays within `tolerance` of the final one."""
    far = np.linalg.norm(observations - observations[-1], axis=1) > tolerance
    moving = np.nonzero(far)[0]
    return int(moving[-1]) + 1 if moving.size else 0


def first_disagreement(distances: Iterable[float], threshold: float, consecutive: int) -> int | None:
    """The first step of the first run of `consecutive` steps whose action distance exceeds `threshold` (reads
    the distances only that far)."""
    run = 0
    for t, distance in enumerate(distances):
        run = run + 1 if distance > threshold else 0
        if run >= consecutive:
            return t - consecutive + 1
    return None


def takeover_step(
    trace: RolloutTrace, args: TakeoverArgs, expert_action: Callable[[int], np.ndarray] | None = None
) -> tuple[int, str]:
    """The step where the expert takes over `trace` (a failed rollout), and the rule that decided it.
    `expert_action(t)`: the expert's action at step t's state, asked only as far as the rule needs."""
    if args.rule == "disagreement":
        if expert_action is None:
            raise ValueError("the disagreement rule needs the expert's actions along the rollout")
        distances = (
            float(np.linalg.norm(np.asarray(trace.actions[t], np.float64) - expert_action(t)))
            for t in range(len(trace.actions))
        )
        t = first_disagreement(distances, args.threshold, args.consecutive)
        if t is not None:
            return max(0, t - args.backoff), "disagreement"
    observations = np.stack([np.asarray(o["environment_state"], np.float64) for o in trace.observations])
    return max(0, stall_step(observations, args.stall_tolerance) - args.backoff), "backoff"


def choose_takeover(
    trace: RolloutTrace, args: TakeoverArgs, expert_first_action: Callable[[dict, np.ndarray], np.ndarray]
) -> TakeoverPoint:
    """The takeover point of a failed rollout; `expert_first_action(obs, state)`: the expert's action if it took
    over at that observation and whole state (clipped to the suites' [-1, 1] action box, like the policy's executed
    actions)."""

    def expert_action(t: int) -> np.ndarray:
        action = expert_first_action(trace.observations[t], trace.states[t])
        return np.clip(np.asarray(action, np.float64), -1.0, 1.0)

    step, rule = takeover_step(trace, args, expert_action)
    return TakeoverPoint(step, np.asarray(trace.states[step], np.float64), rule)
