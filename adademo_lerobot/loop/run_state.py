"""What `adademo-run` keeps between invocations: the finished stages and the settings that define the run
(`run_state.json`; a rerun must keep them), and where the run's data is (`RunData`)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from adademo_lerobot.collectors import CollectorConfig
from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import atomic_write_text
from adademo_lerobot.dataset.ledger import setting_changes
from adademo_lerobot.strategies import StrategyConfig
from adademo_lerobot.suites import SuiteConfig


def read_run_state(run_dir: Path) -> dict | None:
    """`run_dir`'s run_state.json (None: there is none), refused in one line when it is not one adademo-run wrote
    (the run is not ours, or the file was edited)."""
    path = Path(run_dir) / "run_state.json"
    if not path.exists():
        return None
    try:
        state = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise AdaDemoError(
            f"{path} is not valid JSON ({err}): not an adademo-run state; use another run folder"
        ) from None
    if (
        not isinstance(state, dict)
        or not isinstance(state.get("settings"), dict)
        or not isinstance(state.get("done"), dict)
    ):
        raise AdaDemoError(
            f"{path} holds no run settings and stages: not an adademo-run state; use another run folder"
        )
    return state


class RunState:
    """Finished stages of a run, plus the settings that define it (a rerun must keep them). `on_stage` hears
    `[done] NAME` for a stage an earlier invocation finished and `[run]  NAME` for one that runs (the command
    prints them). A run started before a field of its strategy, suite, collector or takeover settings existed ran
    as that field's default (`config_field_defaults`)."""

    def __init__(self, run_dir: Path, settings: dict, on_stage: Callable[[str], None] | None = None):
        self.path = run_dir / "run_state.json"
        self._on_stage = on_stage or (lambda line: None)
        state = read_run_state(run_dir)
        if state is not None:
            for key, default in SETTINGS_ADDED_LATER.items():  # a run started before the setting existed
                state["settings"].setdefault(key, default)
            for name, defaults in config_field_defaults(settings).items():
                journaled, current = state["settings"].get(name), settings.get(name)
                configs = isinstance(journaled, dict) and isinstance(current, dict)
                if configs and journaled.get("type") == current.get("type"):
                    added = (current.keys() - journaled.keys()) & defaults.keys()  # since it started
                    for key in added:
                        journaled[key] = defaults[key]
            legacy, current = state["settings"].get("strategy"), settings.get("strategy")
            if isinstance(legacy, str) and isinstance(current, dict) and legacy == current.get("type"):
                # Started before 0.3, when the strategy was a name and its values shared top-level flags that
                # applied or not by strategy: only the type can be checked.
                state["settings"]["strategy"] = current
            diffs = sorted(
                k
                for k in set(settings) | set(state["settings"])
                if settings.get(k) != state["settings"].get(k)
                and (k in FIXED_SETTINGS or k in FIXED_SINCE_RECORDED and k in state["settings"])
            )
            if diffs:
                before = state["settings"]
                changes = [c for k in diffs for c in setting_changes(k, before.get(k), settings.get(k))]
                raise AdaDemoError(
                    f"{run_dir} was started with other settings ({'; '.join(changes)}); "
                    "rerun with the same recipe and flags, or use another --run_dir"
                )
            self.done = state["done"]
            self.interrupted = state.get("interrupted", {})
            settings = {**state["settings"], **settings}
        else:
            self.done = {}
            self.interrupted = {}
        self.settings = settings
        self._save()

    def _save(self) -> None:
        state = {"settings": self.settings, "done": self.done}
        if self.interrupted:
            state["interrupted"] = self.interrupted
        atomic_write_text(self.path, json.dumps(state, indent=2))

    def stage(self, name: str, fn, *args):
        """`fn(*args)`, unless an earlier invocation finished the stage: then its remembered (JSON) result.

        A stage's `seconds` add up every invocation that worked on it, so a resumed stage reports its whole
        cost; time lost to a kill that gave no chance to record it (SIGKILL, power) is not counted."""
        if name in self.done:
            self._on_stage(f"[done] {name}")
            return self.done[name]["result"]
        self._on_stage(f"[run]  {name}")
        start = time.perf_counter()
        earlier = self.interrupted.get(name, 0.0)
        try:
            result = fn(*args)
        except BaseException:
            self.interrupted[name] = round(earlier + time.perf_counter() - start, 1)
            with contextlib.suppress(OSError):  # a full disk must not hide the failure being reported
                self._save()
            raise
        self.interrupted.pop(name, None)
        self.done[name] = {"result": result, "seconds": round(earlier + time.perf_counter() - start, 1)}
        self._save()
        return result


# Settings whose change would make a resumed run a different experiment.
FIXED_SETTINGS = (
    "suite",
    "strategy",
    "initial_demos_per_task",
    "seed",
    "eval",
    "sampler_alpha",
    "sampler",
    "policy_type",
    "start",
    "lr_schedule",
    "demo_start",
    "takeover",
)
# Settings fixed once a run records them: runs started before they were recorded did not, with values unknown.
FIXED_SINCE_RECORDED = ("train_seed", "batch_size", "autonomous_weight", "collector")
# Settings that runs started by an earlier release do not record, with the value those runs used.
SETTINGS_ADDED_LATER = {"lr_schedule": "preset", "demo_start": "initial", "takeover": None}
# Fields of the config settings whose default does not do what runs journaled before the field did: such a run
# is refused rather than resumed as the default. (Takeover corrections retried and had no fallback then.)
FIELDS_WITHOUT_A_PAST_DEFAULT = {"takeover": ("attempts", "fallback")}
# The config settings that are a choice among registered types, by the setting's name.
CONFIG_REGISTRIES = {"strategy": StrategyConfig, "suite": SuiteConfig, "collector": CollectorConfig}


def config_field_defaults(settings: dict) -> dict[str, dict]:
    """Per config setting (the takeover's, and the strategy's, suite's and collector's of the type `settings`
    name): the fields a run or round journaled before they existed ran as, their defaults (a new field's default
    keeps the behaviour from before it, docs/extending.md), but `FIELDS_WITHOUT_A_PAST_DEFAULT`."""
    defaults = {"takeover": TakeoverArgs().to_dict()}
    for name, registry in CONFIG_REGISTRIES.items():
        kind = settings.get(name, {}).get("type") if isinstance(settings.get(name), dict) else None
        if kind in registry.get_known_choices():
            defaults[name] = registry.get_choice_class(kind)().to_dict()
    return {
        name: {k: v for k, v in fields.items() if k not in FIELDS_WITHOUT_A_PAST_DEFAULT.get(name, ())}
        for name, fields in defaults.items()
    }


def saved_stage(run_dir: Path, name: str) -> dict | None:
    """A finished stage of an earlier invocation of this run (read only)."""
    state = read_run_state(run_dir)
    if state is None:
        return None
    return {**state["done"][name], "settings": state["settings"]} if name in state["done"] else None


@dataclass
class RunData:
    """The run's dataset, the last round of its history before the run, and the user's checkpoint (if any)."""

    root: Path
    repo_id: str
    base_round: int
    checkpoint: Path | None

    @classmethod
    def of_stage(cls, result: dict) -> RunData:
        checkpoint = result["checkpoint"]
        return cls(
            Path(result["dataset_root"]),
            result["repo_id"],
            result["base_round"],
            checkpoint and Path(checkpoint),
        )

    @classmethod
    def collected(cls, run_dir: Path) -> RunData:
        """Demonstrations the expert collects into the run folder (relative to it, so a copied run folder
        keeps working on its own copy)."""
        return cls(run_dir / "dataset", f"local/{run_dir.name}", 0, None)
