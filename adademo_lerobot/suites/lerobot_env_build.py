"""Building a LeRobot env for the `lerobot_env` suite, and the checks that refuse one in one line before a run:
LeRobot's env config from the suite's fields, the plugin or gym package that registers it, the task names it
knows, the spaces it declares and whether the same seed gives the same start."""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib
import importlib.metadata
import inspect
import logging
import traceback
from pathlib import Path

import gymnasium as gym
import numpy as np

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.suites.base import (
    check_task_names,
)

log = logging.getLogger(__name__)

DETERMINISM_SEEDS = (12345, 777)
_NOTED: set[str] = set()


PLUGIN_DOCS = 'docs/lerobot-env.md, "Write your own plugin"'


def env_config(fields: dict):
    """LeRobot's `EnvConfig` of `fields["type"]` (plugins discovered as LeRobot does), with the other fields."""
    import draccus
    from lerobot.envs.configs import EnvConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    kind = fields.get("type")
    known = sorted(EnvConfig.get_known_choices())
    if not kind:
        raise AdaDemoError(f"--suite.env.type is required: a LeRobot env type ({', '.join(known)})")
    try:
        cls = EnvConfig.get_choice_class(kind)
    except KeyError:
        close = difflib.get_close_matches(kind, known, n=1)
        raise AdaDemoError(
            f"unknown --suite.env.type={kind!r}{f' (did you mean {close[0]}?)' if close else ''}: LeRobot knows "
            f"{', '.join(known)}; a plugin's type is the name its EnvConfig registers with "
            "@EnvConfig.register_subclass, found when its distribution, named lerobot_env_*, is installed"
            f"{unimported_plugins()}"
        ) from None
    if inspect.isabstract(cls):  # LeRobot's EnvConfig leaves gym_kwargs abstract
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise AdaDemoError(
            f"the {kind} env config ({cls.__module__}.{cls.__name__}) does not define {missing}: a plugin's "
            "EnvConfig must define the property gym_kwargs, the keyword arguments gym.make passes to its env's "
            f"constructor ({{}} if none; {PLUGIN_DOCS})"
        )
    values = {k: v for k, v in fields.items() if k != "type"}
    unknown = sorted(set(values) - {f.name for f in dataclasses.fields(cls) if f.init})
    if unknown:
        raise AdaDemoError(f"--suite.env.{unknown[0]} is not a field of LeRobot's {kind} env config")
    try:
        return draccus.decode(cls, values)
    except Exception as err:  # noqa: BLE001  (draccus raises several types for a value it cannot decode)
        raise AdaDemoError(f"--suite.env: {one_line(err)}") from None


def env_fields(cfg) -> dict:
    """An env config as the dict stored with the dataset (every field, JSON values)."""
    import json

    import draccus

    encoded = draccus.encode(cfg)
    skip = {"features", "features_map"}  # LeRobot's feature descriptions, derived from the type
    return {
        "type": cfg.type,
        **{k: v for k, v in json.loads(json.dumps(encoded, default=str)).items() if k not in skip},
    }


def unimported_plugins() -> str:
    """Why an installed env plugin may be missing from LeRobot's types, for the unknown-type message."""
    import sys

    names = {d.metadata.get("Name") or "" for d in importlib.metadata.distributions()}
    failed = sorted(n for n in names if n.startswith("lerobot_env_") and n not in sys.modules)
    hyphens = sorted(n for n in names if n.lower().startswith("lerobot-env-"))
    notes = (
        [f"; installed but not importable as a module of that name: {', '.join(failed)}"] if failed else []
    )
    if hyphens:
        notes.append(
            f"; LeRobot imports only distributions named with underscores (lerobot_env_NAME): {', '.join(hyphens)}"
        )
    return "".join(notes)


def one_line(err: BaseException, limit: int = 300) -> str:
    return " ".join(str(err).split())[:limit]


def uses_gym_registry(cfg) -> bool:
    """Whether LeRobot makes this env with `gym.make(cfg.gym_id)` (the default `create_envs`); benchmarks such as
    LIBERO make their envs themselves, without gym ids."""
    from lerobot.envs.configs import EnvConfig

    return type(cfg).create_envs is EnvConfig.create_envs


def gym_id_of(cfg, task: str) -> str:
    """The gym id the config builds for `task` (`package_name/task` unless the plugin says otherwise)."""
    probe = copy.copy(cfg)
    probe.task = task
    return probe.gym_id


def registered_as(name: str) -> list[str]:
    """The registered gym ids of that name, in any namespace."""
    name = name.split("/")[-1]
    return sorted(i for i in gym.registry if i.split("/")[-1] == name)


def import_env_package(cfg) -> None:
    """Import the config's `package_name` as LeRobot's `make_env` does when the gym id is not registered yet (a
    plugin's own distribution is already imported by plugin discovery): a failure says what the plugin lacks."""
    from lerobot.envs.configs import EnvConfig

    if not uses_gym_registry(cfg) or cfg.gym_id in gym.registry:
        return
    name, cls = cfg.package_name, type(cfg)
    try:
        importlib.import_module(name)
    except ModuleNotFoundError as err:
        if err.name and not (name == err.name or name.startswith(f"{err.name}.")):  # one of its own imports
            raise AdaDemoError(
                f"importing {name!r}, the package of the {cfg.type} env, failed: {err}"
            ) from None
        found = registered_as(cfg.task or "")
        hint = (
            f"; its task {cfg.task!r} is registered as {found[0]!r}, so package_name must return "
            f"{found[0].split('/')[0]!r}"
            if found and "/" in found[0]
            else ""
        )
        if cls.package_name is not EnvConfig.package_name:
            raise AdaDemoError(
                f"the {cfg.type} env config ({cls.__module__}.{cls.__name__}) has package_name={name!r}, which "
                "is not an importable module: package_name must be the module whose import registers the env's "
                f"gym ids, and their namespace{hint} ({PLUGIN_DOCS})"
            ) from None
        if cls.__module__.startswith("lerobot."):  # a built-in env type whose simulator is not installed
            extras = importlib.metadata.metadata("lerobot").get_all("Provides-Extra") or []
            extra = f", or LeRobot's extra: pip install 'lerobot[{cfg.type}]'" if cfg.type in extras else ""
            raise AdaDemoError(
                f"the {cfg.type} env needs the package {name!r}, which is not installed: pip install "
                f"{name.replace('_', '-')}{extra}"
            ) from None
        raise AdaDemoError(
            f"the {cfg.type} env config ({cls.__module__}.{cls.__name__}) does not define package_name, so "
            f"LeRobot imports {name!r}, which does not exist: a plugin's EnvConfig must define the property "
            f"package_name, the module whose import registers its gym ids and their namespace{hint} ({PLUGIN_DOCS})"
        ) from None
    except Exception as err:  # noqa: BLE001  (a plugin's import may fail in any way)
        raise AdaDemoError(
            f"importing {name!r}, the package of the {cfg.type} env, failed: {type(err).__name__}: {one_line(err)}"
        ) from None


def env_tasks(cfg) -> list[str]:
    """The tasks this config builds: the gym ids its package registers under its namespace, without the namespace
    (the config's own task first), else just its config's task."""
    namespace = getattr(cfg, "package_name", None)
    registered = sorted(
        spec.id.split("/", 1)[1]
        for spec in gym.registry.values()
        if namespace and spec.namespace == namespace
    )
    if not uses_gym_registry(cfg):
        return registered or [t for t in [cfg.task] if t]
    default = [cfg.task] if cfg.task and gym_id_of(cfg, cfg.task) in gym.registry else []
    return default + [t for t in registered if t not in default and gym_id_of(cfg, t) in gym.registry]


def task_spellings(cfg, task: str) -> list[str]:
    """The values of `task` the config builds the env of: as given, without its namespace, or with it (the
    user's spelling, unless another one names the same registered env)."""
    if gym_id_of(cfg, task) in gym.registry:
        return [task]
    name = task.split("/")[-1]
    fits = []
    for candidate in dict.fromkeys([name, *registered_as(name)]):
        built = gym_id_of(cfg, candidate)
        if built in gym.registry and (built == task or ("/" not in task and built.split("/")[-1] == task)):
            fits.append(candidate)
    return fits


def canonical_task(cfg, task: str) -> str:
    """`task` as the config spells it (`lerobot_env_x/Task-v0` -> `Task-v0`), else as given."""
    fits = task_spellings(cfg, task)
    return fits[0] if len(fits) == 1 else task


def resolve_tasks(cfg, requested: list[str]) -> list[str]:
    """The requested tasks (default: the config's task), each as the config spells it, all built as registered
    gym ids; otherwise one line on what the user should pass, or what the plugin must register."""
    import_env_package(cfg)
    known = env_tasks(cfg)
    if not uses_gym_registry(cfg):
        tasks = requested or known[:1]
        check_task_names(tasks, known, f"{cfg.type} env")
        return tasks
    if not known:
        gym_id, found = gym_id_of(cfg, cfg.task or "<task>"), registered_as(cfg.task or "")
        if found and "/" in found[0]:
            raise AdaDemoError(
                f"the {cfg.type} env config builds the gym id {gym_id!r} (package_name/task), which is not "
                f"registered; its task is registered as {found[0]!r}: package_name must return the namespace of "
                f"the gym ids, {found[0].split('/')[0]!r} ({PLUGIN_DOCS})"
            )
        raise AdaDemoError(
            f"the {cfg.type} env config builds the gym id {gym_id!r}, which importing {cfg.package_name!r} did "
            f"not register: the plugin must gym.register its envs as '{cfg.package_name}/<task>' when imported "
            f"({PLUGIN_DOCS})"
        )
    tasks = []
    for task in requested or known[:1]:
        fits = task_spellings(cfg, task)
        if len(fits) == 1:
            if fits[0] != task:
                log.info("note: --suite.tasks: %s is the %s env's task %s", task, cfg.type, fits[0])
            tasks.append(fits[0])
            continue
        if len(fits) > 1:
            raise AdaDemoError(
                f"--suite.tasks: {task!r} names several {cfg.type} envs ({', '.join(fits)}); give one of them"
            )
        name = task.split("/")[-1]
        if "/" in task and name in known:
            raise AdaDemoError(
                f"--suite.tasks: {task!r} is not an id of the {cfg.type} env, whose ids are "
                f"'{cfg.package_name}/<task>'; give the task without its namespace: --suite.tasks={name}"
            )
        check_task_names([task], known, f"{cfg.type} env")
    check_task_names(tasks, tasks, f"{cfg.type} env")  # each is known by now: only a task listed twice
    return tasks


def build_env(cfg, task: str) -> gym.Env:
    """One env of `task`, made by LeRobot's `make_env` (a sub-env of its vector env, without the step limit:
    the suite ends episodes itself). A config whose `gym_kwargs` the env's constructor does not take (a plugin's
    config shared by several tasks) is retried without those arguments, with a note. An env that cannot be made
    is one line naming the plugin's error."""
    from lerobot.envs.factory import make_env

    cfg = copy.deepcopy(cfg)
    if hasattr(cfg, "task"):
        cfg.task = task
    try:
        vector = next(iter(next(iter(make_env(cfg, n_envs=1, use_async_envs=False).values())).values()))
        env = vector.envs[0]
    except TypeError as err:
        if "unexpected keyword argument" not in str(err) or not uses_gym_registry(cfg):
            raise AdaDemoError(construction_failed(cfg, task, err)) from None
        env = make_with_accepted_kwargs(cfg, task)
    except AdaDemoError:
        raise
    except Exception as err:  # noqa: BLE001  (the plugin's constructor may fail in any way)
        raise AdaDemoError(construction_failed(cfg, task, err)) from None
    wrapper = env
    while isinstance(wrapper, gym.Wrapper):  # the suite counts steps; the env's own limit must not cut first
        if isinstance(wrapper, gym.wrappers.TimeLimit):
            wrapper._max_episode_steps = 10**9
        wrapper = wrapper.env
    return env


def make_with_accepted_kwargs(cfg, task: str) -> gym.Env:
    """`gym.make` with only the `gym_kwargs` the env's constructor takes, saying once which were left out."""
    spec = gym.spec(cfg.gym_id)
    creator = spec.entry_point
    if isinstance(creator, str):
        creator = gym.envs.registration.load_env_creator(creator)
    accepted = inspect.signature(creator).parameters
    kwargs = {k: v for k, v in cfg.gym_kwargs.items() if k in accepted or k == "max_episode_steps"}
    note = (
        f"note: the {cfg.type} env config passes {', '.join(sorted(set(cfg.gym_kwargs) - set(kwargs)))}, "
        f"which {cfg.gym_id} does not take: left out"
    )
    if note not in _NOTED:
        _NOTED.add(note)
        log.info(note)
    try:
        return gym.make(cfg.gym_id, disable_env_checker=True, **kwargs)
    except Exception as err:  # noqa: BLE001  (the plugin's constructor may fail in any way)
        raise AdaDemoError(construction_failed(cfg, task, err)) from None


def construction_failed(cfg, task: str, err: BaseException) -> str:
    """One line: the plugin's error, where it was raised, and what to change."""
    frames = traceback.extract_tb(err.__traceback__)
    where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno})" if frames else ""
    kwargs = ", ".join(f"{k}={v!r}" for k, v in getattr(cfg, "gym_kwargs", {}).items())
    return (
        f"the {cfg.type} env could not be made for task {task} (gym.make({cfg.gym_id!r}, {kwargs})): "
        f"{type(err).__name__}: {one_line(err, 200)}{where}; fix that --suite.env.* value, or the plugin's "
        "gym_kwargs and its env's constructor"
    )


def check_spaces(env: gym.Env, name: str) -> None:
    """The env's observation is a dict with LeRobot's state keys, its action a Box (clipped to, and its shape
    checked against, the expert's and the policy's actions)."""
    spaces = env.observation_space
    if not isinstance(spaces, gym.spaces.Dict) or "agent_pos" not in spaces.spaces:
        raise AdaDemoError(
            f"{name} observes {type(spaces).__name__}{list(getattr(spaces, 'spaces', {})) or ''}: the suite "
            "needs a gymnasium.spaces.Dict with LeRobot's state keys, agent_pos (the robot) and optionally "
            f"environment_state (the objects, the goal) ({PLUGIN_DOCS})"
        )
    if not isinstance(env.action_space, gym.spaces.Box):
        raise AdaDemoError(
            f"{name} has the action space {env.action_space}: the suite needs a gymnasium.spaces.Box "
            f"(continuous actions, clipped to its bounds; the dataset's `action` has its shape) ({PLUGIN_DOCS})"
        )


def first_observation(env: gym.Env, seed: int) -> dict:
    obs, _ = env.reset(seed=int(seed))
    return {k: np.array(v, copy=True) for k, v in obs.items() if not isinstance(v, dict)}


def check_deterministic(env: gym.Env, name: str) -> None:
    """Two resets with the same seed, another one between them, must give the same first observation."""
    a, b = DETERMINISM_SEEDS
    first = first_observation(env, a)
    first_observation(env, b)
    again = first_observation(env, a)
    if any(not np.array_equal(first[k], again[k]) for k in first):
        raise AdaDemoError(
            f"{name} is not deterministic under its reset seed: reset(seed={a}) gave two different first "
            "observations (checked before anything is written), so its seeds cannot stand for initial states; "
            "use an env whose reset(seed) fixes the layout, or one with an exact state restore"
        )
    if all(np.array_equal(first[k], first_observation(env, b)[k]) for k in first):
        log.info(
            "note: %s starts every episode the same whatever the seed: AdaDemo has no initial states to choose "
            "(enable the env's randomization, e.g. --suite.env.random_block_position=true)",
            name,
        )
