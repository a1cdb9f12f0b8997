"""Shared entry-point plumbing: draccus parsing with LeRobot's conventions and one-line errors.

Commands parse first and import their implementation (torch, LeRobot, the simulators) only afterwards, so
`--help`, a misspelled flag or a bad value answers at once. LeRobot's own config registries (policies, robots,
teleoperators) import torch, so a command's config declares those fields with `lerobot_choice(kind)`: the first
parse reads them as plain dicts (`--help`, flag errors and the config's `validate()` answer from it), and only
then is LeRobot imported and the config parsed again with LeRobot's types in their place.

`--config_path` always goes straight to draccus so YAML recipes and presets work; for LeRobot's training config,
`--policy.path` is taken out of the flags as `lerobot.configs.parser.wrap` does and handed to the config
(`use_pretrained_policy`): only this module reads the command line, never a config or a library function.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib
import json
import logging
import os
import re
import signal
import sys
import tempfile
import threading
import typing
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from types import MappingProxyType
from typing import Any

from adademo_lerobot.core.errors import AdaDemoError, MachineError, machine_cause
from adademo_lerobot.core.interrupts import command_starts, raise_keyboard_interrupt
from adademo_lerobot.core.plugins import import_plugins
from adademo_lerobot.loop.configs import LEROBOT_CHOICE
from adademo_lerobot.loop.recipe_file import check_recipe_file


def lerobot_choice_type(kind: str) -> type:
    """LeRobot's config base class for `kind`, with every choice registered (this is the import that costs
    seconds)."""
    if kind == "policy":
        import lerobot.policies  # noqa: F401  (registers ACT/Diffusion/... for --policy.type)
        from lerobot.configs.policies import PreTrainedConfig

        return PreTrainedConfig
    # The robots and teleoperators lerobot-record knows, plus installed plugins, by type name.
    import lerobot.scripts.lerobot_record  # noqa: F401
    from lerobot.robots.config import RobotConfig
    from lerobot.teleoperators.config import TeleoperatorConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    return {"robot": RobotConfig, "teleop": TeleoperatorConfig}[kind]


@functools.cache  # a command asks up to three times; the walk resolves every type hint of the config
def choice_fields(config_cls: type, prefix: str = "") -> MappingProxyType[str, str]:
    """Dotted path -> kind of every `lerobot_choice` field of a (nested) dataclass config (read-only: cached)."""
    found = {}
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        if LEROBOT_CHOICE in f.metadata:
            found[prefix + f.name] = f.metadata[LEROBOT_CHOICE]
        elif dataclasses.is_dataclass(hints[f.name]):
            found.update(choice_fields(hints[f.name], f"{prefix}{f.name}."))
    return MappingProxyType(found)


def with_lerobot_types(config_cls: type, types: dict[str, type]) -> type:
    """`config_cls` with each dotted field of `types` retyped `T | None` (LeRobot's config in place of a dict)."""
    own, nested = [], defaultdict(dict)
    for path, kind_type in types.items():
        head, _, rest = path.partition(".")
        if rest:
            nested[head][rest] = kind_type
        else:
            own.append((head, kind_type | None, dataclasses.field(default=None)))
    hints = typing.get_type_hints(config_cls)
    for head, sub_types in nested.items():
        sub_cls = with_lerobot_types(hints[head], sub_types)
        own.append((head, sub_cls, dataclasses.field(default_factory=sub_cls)))
    return dataclasses.make_dataclass(config_cls.__name__, own, bases=(config_cls,))


def _pop_arg(name: str, argv: list[str]) -> tuple[str | None, list[str]]:
    """The value of `--name=value` (or `--name value`) and argv without it."""
    value, rest, skip = None, [], False
    for i, arg in enumerate(argv):
        if skip:
            skip = False
            continue
        if arg.startswith(f"--{name}="):
            value = arg.split("=", 1)[1]
        elif arg == f"--{name}" and i + 1 < len(argv):
            value, skip = argv[i + 1], True
        else:
            rest.append(arg)
    return value, rest


def dict_fields(config_cls: type) -> list[str]:
    """Dotted paths of dict fields given flag by flag: a LeRobot env's config in `--suite.env.type=so101
    --suite.env.random_block_position=true` (the lerobot_env suite builds it with LeRobot's own registry)."""
    hints = typing.get_type_hints(config_cls) if dataclasses.is_dataclass(config_cls) else {}
    return ["suite.env"] if "suite" in hints else []


def _fold_choice_args(args: list[str], paths: list[str]) -> list[str]:
    """`--train.policy.type=act --train.policy.dim_model=64` -> `--train.policy={"type": "act", ...}` (values
    stay strings: the first parse only needs to know what was given)."""
    raw: dict[str, dict[str, str]] = {}
    rest, i = [], 0
    while i < len(args):
        arg = args[i]
        path = next((p for p in paths if arg.startswith(f"--{p}.")), None)
        if path is None:
            rest.append(arg)
        else:
            key, eq, value = arg[len(path) + 3 :].partition("=")
            if not eq and i + 1 < len(args):
                value, i = args[i + 1], i + 1
            raw.setdefault(path, {})[key] = value
        i += 1
    return rest + [f"--{path}={json.dumps(values)}" for path, values in raw.items()]


_NOTED: set[str] = set()


def retyped_recipe(config_cls: type, config_path: str | None, args: list[str], folder: str) -> str | None:
    """The recipe, or a copy of it in `folder` for a command line that picks another type for one of its choices
    (`--strategy.type=uniform` on a recipe whose strategy is budgeted): the recipe's settings the new type does
    not have are dropped (said once), the ones it has are kept (a budget stays the budget)."""
    if config_path is None:
        return None
    import draccus
    import yaml

    content = yaml.safe_load(Path(config_path).read_text()) or {}
    hints = typing.get_type_hints(config_cls)
    changed = False
    for name, section in content.items():
        kind = hints.get(name)
        picked = next((a.split("=", 1)[1] for a in args if a.startswith(f"--{name}.type=")), None)
        is_choice = isinstance(kind, type) and issubclass(kind, draccus.ChoiceRegistry)
        if not (is_choice and isinstance(section, dict) and picked) or section.get("type") == picked:
            continue
        try:
            fields = {f.name for f in dataclasses.fields(kind.get_choice_class(picked))}
        except KeyError:
            continue  # an unknown type: the parse says so
        dropped = sorted(k for k in section if k != "type" and k not in fields)
        content[name] = {**{k: v for k, v in section.items() if k in fields}, "type": picked}
        changed = True
        note = f"note: --{name}.type={picked} replaces the recipe's {section.get('type')} {name}" + (
            f" (its {', '.join(dropped)} not used)" if dropped else ""
        )
        if dropped and note not in _NOTED:
            _NOTED.add(note)
            print(note, flush=True)
    if not changed:
        return config_path
    path = Path(folder) / Path(config_path).name
    path.write_text(yaml.safe_dump(content))
    return str(path)


def parse_light(config_cls: type, argv: list[str], known_only: bool = False) -> Any:
    """Parse `config_cls` without importing LeRobot (`lerobot_choice` fields become dicts). `known_only`:
    flags and config-file keys the class does not know are left to a later parse instead of refused."""
    import draccus
    import yaml
    from draccus.argparsing import ArgumentParser

    config_path, args = _pop_arg("config_path", argv)
    args = _fold_choice_args(args, [*choice_fields(config_cls), *dict_fields(config_cls)])
    with tempfile.TemporaryDirectory() as tmp:
        config_path = retyped_recipe(config_cls, config_path, args, tmp)
        if not known_only:
            return draccus.parse(config_class=config_cls, config_path=config_path, args=args)
        if config_path is not None:  # keep the keys this class knows (the rest is LeRobot's)
            names = {f.name for f in dataclasses.fields(config_cls)}
            content = yaml.safe_load(Path(config_path).read_text()) or {}
            config_path = Path(tmp) / "known.yaml"
            config_path.write_text(yaml.safe_dump({k: v for k, v in content.items() if k in names}))
        parser = ArgumentParser(config_class=config_cls, config_path=config_path)
        return parser.parse_known_args(args)[0]


def parse_config(config_cls: type, argv: list[str]) -> Any:
    """Parse the full config: `config_cls` with LeRobot's config types in its `lerobot_choice` fields (or a
    LeRobot config itself)."""
    import draccus

    choices = choice_fields(config_cls)
    if choices:
        config_cls = with_lerobot_types(config_cls, {p: lerobot_choice_type(k) for p, k in choices.items()})
    config_path, args = _pop_arg("config_path", argv)
    args = _fold_choice_args(args, dict_fields(config_cls))
    if not hasattr(config_cls, "__get_path_fields__"):
        with tempfile.TemporaryDirectory() as tmp:
            config_path = retyped_recipe(config_cls, config_path, args, tmp)
            return draccus.parse(config_class=config_cls, config_path=config_path, args=args)
    # LeRobot's training config: --policy.type, or --policy.path with --policy.* overrides of its config. The path
    # is read here, from this command's own flags, and handed to the config (which never reads sys.argv).
    from lerobot.configs import parser

    lerobot_choice_type("policy")
    policy_path, overrides = parser.get_path_arg("policy", args), parser.get_cli_overrides("policy", args)
    cfg = draccus.parse(
        config_class=config_cls,
        config_path=config_path,
        args=parser.filter_path_args(config_cls.__get_path_fields__(), args),
    )
    if policy_path:
        cfg.use_pretrained_policy(policy_path, overrides)
    return cfg


def configure_logging() -> None:
    """Our library's messages as a command's output: information plain on stdout, warnings on stderr;
    LeRobot logs every dataset open and video codec choice at INFO, so others show from WARNING."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    ours = logging.getLogger("adademo_lerobot")
    ours.setLevel(logging.INFO)
    ours.propagate = False
    info = logging.StreamHandler(sys.stdout)
    info.setFormatter(logging.Formatter("%(message)s"))
    info.addFilter(lambda record: record.levelno < logging.WARNING)
    warnings = logging.StreamHandler(sys.stderr)
    warnings.setLevel(logging.WARNING)
    warnings.setFormatter(logging.Formatter("warning: %(message)s"))
    ours.handlers = [info, warnings]


def check_moved_flags(config_cls: type, argv: list[str]) -> None:
    """A flag an earlier release had and this one moved (`config_cls.MOVED_FLAGS`: old name -> new dotted name) is
    refused in one line that gives its new spelling, instead of draccus's unknown-argument error."""
    for old, new in getattr(config_cls, "MOVED_FLAGS", {}).items():
        if any(arg == f"--{old}" or arg.startswith(f"--{old}=") for arg in argv):
            raise AdaDemoError(f"--{old} moved: use --{new}")


MISSING_FIELDS = re.compile(
    r"^(?:`(?P<path>[\w.]+)`: )?Missing required field\(s\) (?P<fields>`.+`) for \w+$"
)


def in_flags(message: str) -> str:
    """draccus' "`dataset`: Missing required field(s) `repo_id` for DatasetConfig" as the flags to give
    ("--dataset.repo_id is required"); any other message as it is."""
    match = MISSING_FIELDS.match(message)
    if match is None:
        return message
    prefix = f"{match['path']}." if match["path"] else ""
    flags = [f"--{prefix}{name}" for name in re.findall(r"`(\w+)`", match["fields"])]
    return f"{', '.join(flags)} {'is' if len(flags) == 1 else 'are'} required"


def one_line_usage_errors(parse: Callable, *args) -> Any:
    """`parse(*args)`, with argparse's usage error (an unknown flag, an invalid choice: usage text, then
    `prog: error: ...`, exit 2) turned into our one `error:` line. Help and anything else pass through."""
    import io

    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            result = parse(*args)
    except SystemExit as stop:
        text = captured.getvalue()
        if stop.code == 2 and ": error: " in text:
            print(f"error: {' '.join(text.rsplit(': error: ', 1)[1].split())}", file=sys.stderr)
            sys.exit(2)
        sys.stderr.write(text)
        raise
    except BaseException:
        sys.stderr.write(captured.getvalue())
        raise
    sys.stderr.write(captured.getvalue())
    return result


def _resolve(target: str | Callable) -> Any:
    if not isinstance(target, str):
        return target
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def _close_progress_bars() -> None:
    """Progress bars still open when a command fails end their line first, so that the `error:` line is the
    command's last line, on a line of its own."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):
        bar.close()


def run_command(
    target: str | Callable,
    config_cls: type,
    lerobot_config: str | None = None,
    resume: str = "rerun the same command to resume",
) -> None:
    """Parse `config_cls` from the command line, then import and call `target` ("module:function") with it.

    `--help`, flag errors and `config.validate()` answer from a first parse that imports no LeRobot config;
    with `lerobot_choice` fields, or with `lerobot_config` ("module:Class", a LeRobot config of which
    `config_cls` holds our own flags), the config is then parsed in full. Bad input exits 2 with one `error:`
    line; a failure of the machine (a full disk, an I/O error, a lost Ray cluster) or of the installation (an
    import that fails mid-run) exits 1 with one `error:` line that says the same command resumes; Ctrl-C (or
    SIGTERM, or a closed terminal's SIGHUP) exits 130 saying how to resume (`resume`)."""
    import draccus

    configure_logging()
    argv = sys.argv[1:]
    # Ctrl-C, SIGTERM and a closed terminal's SIGHUP stop a command, once (`raise_keyboard_interrupt`); an ignored
    # signal stays so (Ctrl-C of a job in the background, SIGHUP under nohup).
    command_starts()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
        for sig, default in ((signal.SIGINT, signal.default_int_handler), (signal.SIGHUP, signal.SIG_DFL)):
            if signal.getsignal(sig) is default:
                signal.signal(sig, raise_keyboard_interrupt)
    try:
        try:
            # Before any flag is read: a plugin's strategy, suite or expert parses as a built-in one.
            import_plugins(sys.path)
            check_moved_flags(config_cls, argv)
            check_recipe_file(_pop_arg("config_path", argv)[0])
            cfg = one_line_usage_errors(parse_light, config_cls, argv, lerobot_config is not None)
            if hasattr(cfg, "validate"):
                cfg.validate()
            if lerobot_config is not None:
                cfg = one_line_usage_errors(parse_config, _resolve(lerobot_config), argv)
            elif choice_fields(config_cls):
                cfg = one_line_usage_errors(parse_config, config_cls, argv)
            _resolve(target)(cfg)
        except BaseException:
            _close_progress_bars()
            raise
    except MachineError as err:
        print(f"error: {' '.join(str(err).split())}", file=sys.stderr, flush=True)
        if err.exit_at_once:
            from adademo_lerobot.core.files import COMMIT_LOCK

            sys.stdout.flush()
            COMMIT_LOCK.acquire(timeout=120)  # a commit in another thread finishes (or rolls back) first
            os._exit(1)
        sys.exit(1)
    except AdaDemoError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except (draccus.utils.ParsingError, draccus.utils.DecodingError) as err:
        print(f"error: {in_flags(' '.join(str(err).split()))}", file=sys.stderr)
        sys.exit(2)
    except FileNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    # An import that fails: a package missing (a robot's SDK, an optional extra), or upgraded under a long command
    # before one of its modules was first imported.
    except ImportError as err:
        print(
            f"error: {' '.join(str(err).split())}: a package is missing, or the installed packages changed while "
            "the command ran; install it (or reinstall from the lock: bash setup.sh) and run the same command to "
            "resume",
            file=sys.stderr,
        )
        sys.exit(1)
    except OSError as err:  # the machine: a full disk, an I/O error, a folder that became unwritable
        cause, first = machine_cause(err)
        print(f"error: {cause}: {first}run the same command to resume", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
            print(f"interrupted: {resume}", file=sys.stderr)
        sys.exit(130)
