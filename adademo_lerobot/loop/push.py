"""`adademo-push`: share an adademo dataset on the Hugging Face hub with LeRobot's own `push_to_hub`.

LeRobot uploads the whole dataset folder (so `meta/adademo/` with the suite, the round ledger and the per-round
evaluation records goes too), writes its dataset card and tags the codebase version. We only add to the card:
LeRobot's template has a `dataset_description` slot, which we fill with the suite, the strategies, a per-round
table and the meaning of the `adademo/*` columns; everything else on the card (YAML metadata, `LeRobot` tag,
data_files config, info.json) is LeRobot's, so stock tooling still recognises the dataset.

The hub is whatever `HF_ENDPOINT` names when the process starts (huggingface_hub reads it at import).
huggingface_hub 1.x's `RepoCard.validate` (called by the card push inside `push_to_hub`) posts to a hardcoded
`https://huggingface.co/api/validate-yaml` whatever the endpoint; with another endpoint (a private hub, a mirror,
the tests' local double) we send that one request to the configured endpoint instead (`_card_validation_on_endpoint`).
"""

from __future__ import annotations

import contextlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.layout import (
    ADADEMO_DIR,
    COL_ROUND,
    COL_SOURCE,
    CORRECTION_SOURCE,
    LEDGER_FILE,
    SUITE_FILE,
    TXN_FILE,
)
from adademo_lerobot.dataset.ledger import RoundJournal, ledger_rounds, read_ledger
from adademo_lerobot.dataset.metadata import has_dataset, load_suite_config, read_episode_metadata
from adademo_lerobot.loop.configs import PushConfig
from adademo_lerobot.loop.expand import finish_stale_journals
from adademo_lerobot.strategies import StrategyConfig

log = logging.getLogger(__name__)

# Per-task columns in the round table up to this many tasks; beyond it, one row per (round, task) instead.
MAX_TASK_COLUMNS = 8


# How the card describes each source of episodes: round 0's, and every strategy's own description.
SOURCE_DESCRIPTIONS = {
    "initial": "initial collection: expert demonstrations from random initial states (round 0)",
    "correction": "corrections: the expert took over a failed policy rollout and finished the task from there",
    "human": "demonstrations a person teleoperated on the robot (adademo-record)",
    "imported": "episodes recorded elsewhere (no adademo provenance)",
    "policy": "the policy's own episodes, kept by lerobot-rollout's DAgger (not imitated by default)",
}


def source_description(name: str) -> str:
    try:
        return StrategyConfig.get_choice_class(name).description
    except KeyError:
        return SOURCE_DESCRIPTIONS.get(name, "recorded by another tool")


COLUMN_DESCRIPTIONS = {
    "adademo/round": "expansion round that added the episode (0 = initial collection)",
    "adademo/source": "`initial`, the strategy that added it (`adademo`, `budgeted`, `uniform`, `task_only`), "
    "`correction` (the expert or a person took over a failed policy rollout), `policy` (the policy's own, in "
    "LeRobot's DAgger data) or `imported`",
    "adademo/seed": "seed of the episode's initial state (with the suite, reproduces it)",
    "adademo/initial_state": "the initial state itself (float64 list; MetaWorld: the task's random vector)",
    "adademo/collector": "the expert that recorded it",
    "adademo/suite": "the task-suite family",
    "adademo/start_step": "the step it starts at: 0, or a correction's step of the failed rollout it answers",
    "adademo/start_state": "the whole simulator state it starts from (a robot's joint positions): it replays from it",
}


def is_hub_repo_id(value: str) -> bool:
    """USER/NAME as the hub accepts it (huggingface_hub's own check, with the namespace required)."""
    from huggingface_hub.errors import HFValidationError
    from huggingface_hub.utils import validate_repo_id

    try:
        validate_repo_id(value)
    except HFValidationError:
        return False
    return value.count("/") == 1


def validate(cfg: PushConfig) -> Path:
    if cfg.repo_id is None:
        raise AdaDemoError("--repo_id is required: the hub repo to push to, as USER/NAME")
    if not is_hub_repo_id(cfg.repo_id):
        raise AdaDemoError(
            f"--repo_id={cfg.repo_id!r} is not a hub repo id: use USER/NAME (letters, digits, '-', '_', '.'; "
            "no '--' or '..')"
        )
    if cfg.branch is not None and (not cfg.branch.strip() or any(c in cfg.branch for c in " ~^:?*[\\")):
        raise AdaDemoError(f"--branch={cfg.branch!r} is not a valid branch name")
    if cfg.dataset.root is None:
        raise AdaDemoError("--dataset.root is required (an adademo dataset made by adademo-collect)")
    root = Path(cfg.dataset.root)
    if not has_dataset(root):
        raise AdaDemoError(f"no LeRobot dataset at {root} (missing meta/info.json)")
    load_suite_config(root)  # refuses a dataset that is not an adademo dataset
    if (root / TXN_FILE).exists():
        raise AdaDemoError(
            f"{root} has an unfinished write ({TXN_FILE}); rerun the command that was interrupted "
            "(it rolls the write back or completes it) before pushing"
        )
    # A journal of a round already in the ledger (a kill just before it was archived) is of a finished round.
    unfinished = [r for r in RoundJournal.in_progress(root) if r not in ledger_rounds(root)]
    if unfinished:
        raise AdaDemoError(
            f"round {unfinished[0]} of {root} is unfinished (meta/adademo/journal-round-{unfinished[0]:03d}.jsonl); "
            "rerun the same adademo-expand command to finish it before pushing"
        )
    if read_episode_metadata(root).empty:
        raise AdaDemoError(f"{root} has no episodes to push")
    return root


def resolve_token() -> str:
    """The user's hub token: HF_TOKEN, else the one `huggingface-cli login` saved. Never printed."""
    from huggingface_hub import get_token

    token = get_token()
    if not token:
        raise AdaDemoError("no Hugging Face token: run `huggingface-cli login` or set HF_TOKEN")
    return token


# ---- the card ------------------------------------------------------------------------------------------------


@dataclass
class RoundSummary:
    round: int
    strategies: list[str]
    settings: str  # e.g. "E=10, CAP=50"
    demos: dict[str, int]  # task -> episodes the round added
    evals: dict[str, tuple[int, int]]  # task -> (successes, evaluation episodes), tasks the round evaluated
    total_after: int
    in_ledger: bool


def _settings(records: list[dict]) -> str:
    if not records:
        return ""
    r = records[0]
    values = {
        "E": r.get("target_successes"),
        "CAP": r.get("max_demos_per_task"),
        "N": r.get("demos_per_task"),
        "B": (r.get("extra") or {}).get("budget"),
    }
    return ", ".join(f"{label}={value}" for label, value in values.items() if value is not None)


def summarize_rounds(root: Path, tasks: list[str]) -> list[RoundSummary]:
    """Every round present in the dataset or the ledger, with its demos (from the episodes) and evaluations."""
    eps = read_episode_metadata(root)
    ledger = read_ledger(root)
    rounds = sorted({int(r) for r in eps[COL_ROUND]} | {int(r["round"]) for r in ledger})
    out = []
    for rnd in rounds:
        new = eps[eps[COL_ROUND] == rnd]
        records = [r for r in ledger if r["round"] == rnd]
        strategies = sorted({r["strategy"] for r in records} or set(new[COL_SOURCE]))
        if records and (new[COL_SOURCE] == CORRECTION_SOURCE).any():
            strategies.append(CORRECTION_SOURCE)
        out.append(
            RoundSummary(
                round=rnd,
                strategies=strategies,
                settings=_settings(records),
                demos={t: int((new["task"] == t).sum()) for t in tasks},
                evals={
                    r["task"]: (int(r["successes"]), int(r["eval_episodes"]))
                    for r in records
                    if r.get("eval_episodes")
                },
                total_after=int((eps[COL_ROUND] <= rnd).sum()),
                in_ledger=bool(records),
            )
        )
    return out


def _sr(evaluation: tuple[int, int] | None) -> str:
    if not evaluation:
        return "–"
    successes, episodes = evaluation
    return f"{100 * successes / episodes:.0f}% ({successes}/{episodes})"


def _strategy_cell(s: RoundSummary) -> str:
    name = ", ".join(f"`{x}`" for x in s.strategies)
    if s.settings:
        name += f" ({s.settings})"
    if not s.in_ledger and s.round != 0:
        name += " (no ledger record)"
    return name


def adademo_card_section(root: str | Path, max_task_columns: int = MAX_TASK_COLUMNS) -> str:
    """Markdown for the card's description: suite, strategies, the per-round table, the adademo/* columns."""
    root = Path(root)
    suite = load_suite_config(root)
    eps = read_episode_metadata(root)
    info = json.loads((root / "meta" / "info.json").read_text())
    tasks = [t for t in suite.tasks.split(",") if t]
    tasks += [t for t in dict.fromkeys(eps["task"]) if t not in tasks]
    rounds = summarize_rounds(root, tasks)
    used = sorted({s for r in rounds for s in r.strategies})

    lines = [
        "### AdaDemo",
        "",
        "Grown with **adademo-lerobot**, the method of *AdaDemo: Data-Efficient Demonstration Expansion for "
        "Generalist Robotic Agent*: evaluate the policy, collect expert demonstrations from the initial states "
        "where it fails (more for tasks it solves less often), append them, retrain. It is a standard LeRobot "
        "v3.0 dataset: `LeRobotDataset(repo_id)` loads it.",
        "",
        f"- **Suite:** `{suite.type}` ({suite.obs_type} observations, at most {suite.max_episode_steps} steps per "
        f"episode), {len(tasks)} task(s): {', '.join(f'`{t}`' for t in tasks)}",
        f"- **Episodes:** {len(eps)} ({info.get('total_frames', '?')} frames at {info.get('fps', '?')} fps) from "
        f"{len(rounds)} round(s), round 0 = initial collection",
        "- **Strategies used:**",
        *[f"  - `{s}`: {source_description(s)}" for s in used],
        "",
        "#### Rounds",
        "",
    ]
    if len(tasks) <= max_task_columns:
        rows = [
            [
                s.round,
                _strategy_cell(s),
                *(f"+{s.demos[t]} / {_sr(s.evals.get(t))}" for t in tasks),
                s.total_after,
            ]
            for s in rounds
        ]
        lines += [
            "Per task: demonstrations the round added / the policy's success rate on that round's evaluation "
            "episodes (`–`: the round evaluated no policy on that task).",
            "",
            table(
                ["round", "strategy", *(f"{t}: demos / eval SR" for t in tasks), "episodes after round"],
                rows,
                aligned=False,
                right=(0, len(tasks) + 2),
            ),
        ]
    else:
        rows = []
        for s in rounds:
            total = (sum(v[0] for v in s.evals.values()), sum(v[1] for v in s.evals.values()))
            rows.append(
                [
                    s.round,
                    _strategy_cell(s),
                    f"+{sum(s.demos.values())}",
                    _sr(total if total[1] else None),
                    s.total_after,
                ]
            )
        per_task = [[s.round, t, f"+{s.demos[t]}", _sr(s.evals.get(t))] for s in rounds for t in tasks]
        lines += [
            table(
                ["round", "strategy", "demos added", "eval SR (all tasks)", "episodes after round"],
                rows,
                aligned=False,
                right=(0, 2, 4),
            ),
            "",
            "Per task (`–`: no policy evaluation on that task in that round):",
            "",
            table(["round", "task", "demos added", "eval SR"], per_task, aligned=False, right=(0, 2)),
        ]
    lines += [
        "",
        "#### Per-episode columns",
        "",
        "`meta/episodes` carries these columns besides LeRobot's own:",
        "",
        table(["column", "meaning"], [[f"`{c}`", d] for c, d in COLUMN_DESCRIPTIONS.items()], aligned=False),
        "",
        "#### AdaDemo files",
        "",
        f"- `{SUITE_FILE}`: the suite (type, tasks in one-hot order, observations), enough to rebuild the envs",
        f"- `{LEDGER_FILE}`: one record per round and task (strategy, E, CAP, N, policy, evaluation episodes, "
        "successes, demos added, expert failures, env steps, wall time)",
        f"- `{ADADEMO_DIR}/round-NNN-evaluations.jsonl`: every evaluation outcome of a round (which initial states "
        "the policy failed)",
    ]
    return "\n".join(lines)


# ---- the push ------------------------------------------------------------------------------------------------

HARDCODED_CARD_VALIDATION_URL = "https://huggingface.co/api/validate-yaml"


@contextlib.contextmanager
def _card_validation_on_endpoint():
    """Send `RepoCard.validate`'s request to HF_ENDPOINT (it ignores it) while the push runs, then restore.

    Uses huggingface_hub's public `set_client_factory`: the client the current factory builds (huggingface_hub's
    default one, or whatever the user configured: proxies from HTTPS_PROXY/NO_PROXY, certificates) gets one more
    request hook, which points that one URL at the endpoint; every other request is left alone. (A custom
    transport would not do: httpx ignores the proxy environment variables for a client given a transport.)"""
    import httpx
    from huggingface_hub import constants, set_client_factory
    from huggingface_hub.utils import _http

    endpoint = constants.ENDPOINT.rstrip("/")
    if endpoint == "https://huggingface.co":
        yield
        return
    target = httpx.URL(f"{endpoint}/api/validate-yaml")

    def to_endpoint(request: httpx.Request) -> None:
        # Request hooks run before httpx picks the transport (and proxy) for the URL, so the new URL decides.
        if str(request.url) == HARDCODED_CARD_VALIDATION_URL:
            request.url = target
            request.headers["Host"] = target.netloc.decode("ascii")

    previous = _http._GLOBAL_CLIENT_FACTORY

    def factory() -> httpx.Client:
        client = previous()
        client.event_hooks = {**client.event_hooks, "request": [to_endpoint, *client.event_hooks["request"]]}
        return client

    set_client_factory(factory)
    try:
        yield
    finally:
        set_client_factory(previous)


def _hub_error(err: Exception, repo_id: str) -> AdaDemoError:
    from huggingface_hub import constants

    status = getattr(getattr(err, "response", None), "status_code", None)
    first = " ".join(str(err).split("\n")[0].split())
    if status in (401, 403):
        return AdaDemoError(
            f"the hub at {constants.ENDPOINT} refused the push to {repo_id} ({first}); check that your token "
            "(`huggingface-cli login` or HF_TOKEN) has write access to that namespace"
        )
    return AdaDemoError(f"push of {repo_id} to {constants.ENDPOINT} failed: {first}")


def run_push(cfg: PushConfig) -> str:
    # No command may write the dataset while it is checked, read and uploaded.
    root = cfg.dataset.root
    with exclusive_use(Path(root), "adademo-push") if root else contextlib.nullcontext():
        checked = validate(cfg)
        finish_stale_journals(checked)  # a finished round's journal goes up archived, as expand leaves it
        return push_dataset(cfg, checked)


def push_dataset(cfg: PushConfig, root: Path) -> str:
    token = resolve_token()
    suite = load_suite_config(root)
    section = adademo_card_section(root)

    import httpx
    from huggingface_hub import HfApi, constants
    from huggingface_hub.errors import HfHubHTTPError
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(cfg.repo_id, root=root)  # stock LeRobot must open what we publish
    branch = cfg.branch if cfg.branch not in (None, "main") else None
    api = HfApi(token=token)
    try:
        with _card_validation_on_endpoint():
            # LeRobot does both too (with exist_ok), but it branches from its codebase-version tag, which a new
            # repo does not have yet; created here first, the branch starts from main.
            api.create_repo(cfg.repo_id, repo_type="dataset", private=cfg.private, exist_ok=True)
            if api.repo_info(cfg.repo_id, repo_type="dataset").private != cfg.private:
                log.warning(
                    "%s already exists and is %s; --private only applies when the repo is created",
                    cfg.repo_id,
                    "private" if not cfg.private else "public",
                )
            if branch:
                api.create_branch(cfg.repo_id, branch=branch, repo_type="dataset", exist_ok=True)
            dataset.push_to_hub(
                branch=branch,
                tags=["adademo", suite.type],
                license=cfg.license,
                private=cfg.private,
                dataset_description=section,
            )
    except HfHubHTTPError as err:
        raise _hub_error(err, cfg.repo_id) from None
    except (httpx.TransportError, ConnectionError) as err:
        raise AdaDemoError(f"cannot reach the hub at {constants.ENDPOINT}: {type(err).__name__}") from None

    url = f"{constants.ENDPOINT}/datasets/{cfg.repo_id}" + (f"/tree/{branch}" if branch else "")
    print(
        f"pushed {dataset.meta.total_episodes} episodes ({len(summarize_rounds(root, []))} rounds) "
        f"with the adademo card to {url}"
    )
    return url
