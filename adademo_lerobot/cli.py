"""Shared entry-point plumbing: draccus parsing with LeRobot's conventions and one-line errors.

Commands parse first and import their implementation (torch, LeRobot, the simulators) only afterwards, so
`--help`, a misspelled flag or a bad value answers at once. `--config_path` always goes straight to draccus so
YAML recipes and presets work; for LeRobot's training config, `--policy.path` is taken out of the flags as
`lerobot.configs.parser.wrap` does (the config reads it back with `parser.get_path_arg`).
"""

from __future__ import annotations

import importlib
import logging
import sys
from collections.abc import Callable
from typing import Any

from adademo_lerobot.errors import AdaDemoError


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


def parse_config(config_cls: type, argv: list[str], policy_types: bool = False) -> Any:
    """Parse `config_cls` from argv. `policy_types`: the config holds a LeRobot policy config (`--policy.type`),
    whose choices exist only once `lerobot.policies` is imported (several seconds: torch)."""
    import draccus

    config_path, args = _pop_arg("config_path", argv)
    if policy_types:
        import lerobot.policies  # noqa: F401  (registers ACT/Diffusion configs for --policy.type)
    if hasattr(config_cls, "__get_path_fields__"):
        from lerobot.configs import parser

        args = parser.filter_path_args(config_cls.__get_path_fields__(), args)
    return draccus.parse(config_class=config_cls, config_path=config_path, args=args)


def _resolve(target: str | Callable) -> Callable:
    if callable(target):
        return target
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def run_command(target: str | Callable, config_cls: type, policy_types: bool = False) -> None:
    """Parse `config_cls` from the command line, then import and call `target` ("module:function") with it.
    Bad input exits 2 with one `error:` line; Ctrl-C exits 130 saying how to resume."""
    import draccus

    # LeRobot logs every dataset open and video codec choice at INFO; ours and everyone's warnings show.
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    logging.getLogger("adademo_lerobot").setLevel(logging.INFO)
    try:
        cfg = parse_config(config_cls, sys.argv[1:], policy_types)
        _resolve(target)(cfg)
    except AdaDemoError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except (draccus.utils.ParsingError, draccus.utils.DecodingError) as err:
        print(f"error: {' '.join(str(err).split())}", file=sys.stderr)
        sys.exit(2)
    except FileNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to resume", file=sys.stderr)
        sys.exit(130)
