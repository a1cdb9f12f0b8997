"""Shared entry-point plumbing: draccus parsing (LeRobot's parser, so `--config_path` works) and one-line errors."""

from __future__ import annotations

import logging
import sys
from typing import Callable

from adademo_lerobot.errors import AdaDemoError


def run_command(fn: Callable, config_cls: type) -> None:
    """Parse `config_cls` from the command line and call `fn(cfg)`; bad input exits 2 with one line."""
    import draccus
    from lerobot.configs import parser

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")

    @parser.wrap()
    def entry(cfg: config_cls):  # type: ignore[valid-type]
        return fn(cfg)

    entry.__annotations__["cfg"] = config_cls
    try:
        entry()
    except AdaDemoError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except (draccus.utils.ParsingError, draccus.utils.DecodingError) as err:
        print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to resume", file=sys.stderr)
        sys.exit(130)
