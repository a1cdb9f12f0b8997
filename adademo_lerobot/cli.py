"""Shared entry-point plumbing: draccus parsing with LeRobot's conventions and one-line errors.

Like `lerobot.configs.parser.wrap`, `--policy.path` is taken out of the flags (the config reads it back
with `parser.get_path_arg`), but `--config_path` always goes straight to draccus so YAML recipes and presets
work (LeRobot's wrapper would hand it to `from_pretrained`, which expects JSON).
"""

from __future__ import annotations

import logging
import sys
from typing import Any, Callable

from adademo_lerobot.errors import AdaDemoError


def parse_config(config_cls: type, argv: list[str]) -> Any:
    import draccus
    import lerobot.policies  # noqa: F401  (registers ACT/Diffusion configs for --policy.type)
    from lerobot.configs import parser

    config_path = parser.parse_arg("config_path", argv)
    args = parser.filter_arg("config_path", argv)
    if hasattr(config_cls, "__get_path_fields__"):
        args = parser.filter_path_args(config_cls.__get_path_fields__(), args)
    return draccus.parse(config_class=config_cls, config_path=config_path, args=args)


def run_command(fn: Callable, config_cls: type) -> None:
    """Parse `config_cls` from the command line and call `fn(cfg)`; bad input exits 2 with one line."""
    import draccus

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    try:
        cfg = parse_config(config_cls, sys.argv[1:])
        fn(cfg)
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
