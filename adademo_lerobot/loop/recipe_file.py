"""A recipe file (`--config_path`) as a command first reads it: refused in one line that names the flag when it is
not there or is not a YAML mapping of settings, instead of an error from deep in draccus."""

from __future__ import annotations

from pathlib import Path

from adademo_lerobot.core.errors import AdaDemoError

EXAMPLE = "give a recipe's YAML file (e.g. recipes/quickstart.yaml)"


def check_recipe_file(config_path: str | None) -> None:
    """Nothing to check without a recipe (None)."""
    import yaml

    if config_path is None:
        return
    if not Path(config_path).is_file():
        what = "a folder" if Path(config_path).is_dir() else "no such file"
        raise AdaDemoError(f"--config_path={config_path}: {what}; {EXAMPLE}")
    try:
        content = yaml.safe_load(Path(config_path).read_text())
    except UnicodeDecodeError:
        raise AdaDemoError(f"--config_path={config_path} is not a text file; {EXAMPLE}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err)
        raise AdaDemoError(f"--config_path={config_path} is not valid YAML: {problem}{where}") from None
    if not isinstance(content, dict):
        what = "empty" if content is None else f"a YAML {type(content).__name__}"
        raise AdaDemoError(
            f"--config_path={config_path} is {what}, not a mapping of settings (suite:, train:, ...); {EXAMPLE}"
        )
