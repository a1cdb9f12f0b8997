"""MetaWorld's shipped scripted policies (`metaworld.policies`) as the demonstration collector."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from adademo_lerobot.collectors.base import SimulatedExpertCollector
from adademo_lerobot.suites.metaworld import RAW_OBS_DIM


def scripted_policy(task: str) -> Callable[[dict], np.ndarray]:
    """MetaWorld's shipped expert for `task`, from an env observation (its `environment_state`) to an action."""
    from lerobot.envs.metaworld import TASK_POLICY_MAPPING

    policy = TASK_POLICY_MAPPING[task]()
    # The scripted policies' gains overshoot on purpose and the env clips, as intended. One narrow filter, not
    # `catch_warnings` around every action (that cost ~1 % of a collection's time).
    warnings.filterwarnings("ignore", message=r"Constant\(s\) may be too high", category=UserWarning)

    def act(observation: dict) -> np.ndarray:
        # A copy: some scripted policies edit the observation in place (door-open shifts the handle x).
        raw_obs = np.array(observation["environment_state"][:RAW_OBS_DIM], dtype=np.float64, copy=True)
        return policy.get_action(raw_obs)

    return act


class MetaWorldScriptedExpert(SimulatedExpertCollector):
    name = "metaworld-scripted"

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        return scripted_policy(task)
