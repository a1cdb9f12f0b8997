"""Batched open-loop rollouts in C (`mujoco.rollout`), scored by a reward computed from each rolled-out state:
a planner's candidate action sequences without a Python env step each.

It rolls out from the env's current MuJoCo state (physics and the solver's warm start, so a sequence unfolds
exactly as `env.step` would unfold it), applying each action as the env does (clipped to [-1, 1], mapped to
the actuators' control range, held for `frame_skip` physics steps), and scores the state after every env step
with `reward_of(data)`: of the state reached, or (`as_env_reads`) of exactly what the env's own reward reads after
its `mj_step`s, body positions from the start of the last physics step and joint values from its end.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS


class BatchedRollouts:
    """Rolls out many action sequences of a stock MuJoCo gymnasium env (`act_mean`, `act_rng`, `frame_skip`)
    from its current state. `action_index` picks the env's actions out of wider ones; `threads` > 1 spreads
    the sequences over that many threads."""

    def __init__(
        self,
        raw_env,
        action_index: np.ndarray,
        reward_of: Callable[[mujoco.MjData], float],
        threads: int = 1,
        as_env_reads: bool = False,
    ):
        self._env, self._index, self._reward_of = raw_env, np.asarray(action_index), reward_of
        self._as_env_reads = as_env_reads
        self._model = raw_env.model
        self._frame_skip = int(raw_env.frame_skip)
        self._pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
        self._datas = [mujoco.MjData(self._model) for _ in range(max(1, threads))]
        self._scratch = mujoco.MjData(self._model)
        self._state = np.empty(mujoco.mj_stateSize(self._model, PHYSICS))

    def rewards(self, sequences: np.ndarray) -> np.ndarray:
        """(samples, horizon) rewards of `sequences` (samples, horizon, action dim), each from the current state."""
        live = self._env.data
        mujoco.mj_getState(self._model, live, self._state, PHYSICS)
        # float32, as the task env hands its actions to the stock env
        actions = np.clip(sequences[..., self._index].astype(np.float32), -1.0, 1.0)
        controls = np.repeat(self._env.act_mean + actions * self._env.act_rng, self._frame_skip, axis=1)
        states, _ = self._pool.rollout(
            self._model,
            self._datas,
            self._state[None],
            controls,
            initial_warmstart=live.qacc_warmstart[None],
        )
        fs = self._frame_skip
        ends = states[:, fs - 1 :: fs]
        starts = ends  # positions of the state reached
        if self._as_env_reads and fs > 1:
            starts = states[:, fs - 2 :: fs]  # mj_step computes positions before it integrates
        elif self._as_env_reads:
            starts = np.concatenate(
                [np.broadcast_to(self._state, (len(states), 1, self._state.size)), states[:, :-1]], 1
            )
        out = np.empty(ends.shape[:2])
        scratch = self._scratch
        for k in range(len(ends)):
            for h in range(ends.shape[1]):
                mujoco.mj_setState(self._model, scratch, starts[k, h], PHYSICS)
                mujoco.mj_kinematics(self._model, scratch)
                mujoco.mj_setState(self._model, scratch, ends[k, h], PHYSICS)
                out[k, h] = self._reward_of(scratch)
        return out

    def close(self) -> None:
        self._pool.close()
