"""MuJoCo models parsed once per XML file in a process: each env built gets its own copy of the parsed model.

Most of building a MetaWorld or Adroit env is MuJoCo parsing and compiling its XML (12-21 ms; copying a parsed
model takes 2-4 ms, on the machine of benchmarks/results/loop_speed.md), and a round builds envs often: an
evaluator keeps one task's envs at a time while the strategies evaluate the tasks in turn (342 builds in one local
MT10 round of the budgeted strategy). A copy is the parsed model byte for byte (`mj_copyModel`), and the parsed
model itself is never handed out, so what an env does to its own model (MetaWorld's resets move bodies) never
reaches another env. Listed in docs/lerobot-overrides.md.
"""

from __future__ import annotations

import contextlib
import copy
import threading
from collections import OrderedDict

import mujoco

from adademo_lerobot.core.patching import temporarily_set

KEPT_MODELS = 10  # MT10's models (~19 MB each for MetaWorld, ~7 MB for Adroit): a bounded cost in memory
_parse_xml = mujoco.MjModel.from_xml_path
_parsed: OrderedDict[str, mujoco.MjModel] = OrderedDict()  # by file, most recently used last
_building = threading.Lock()  # the override below is process-wide: one env is built at a time


def _copy_of_parsed(filename: str, assets: dict | None = None) -> mujoco.MjModel:
    if assets is not None:  # models with in-memory assets are not ours to cache
        return _parse_xml(filename, assets)
    model = _parsed.pop(filename, None)
    if model is None:
        model = _parse_xml(filename)
    _parsed[filename] = model
    while len(_parsed) > KEPT_MODELS:
        _parsed.popitem(last=False)
    return copy.copy(model)


@contextlib.contextmanager
def models_parsed_once():
    """While open, `mujoco.MjModel.from_xml_path(file)` (what gymnasium's `MujocoEnv` calls to build its model)
    returns a copy of the model this process parsed from that file, parsing it on first use."""
    with _building, temporarily_set(mujoco.MjModel, "from_xml_path", staticmethod(_copy_of_parsed)):
        yield
