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
import logging
from pathlib import Path

from adademo_lerobot.core.errors import AdaDemoError, MachineError
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.dataset.layout import TXN_FILE
from adademo_lerobot.dataset.metadata import has_dataset, load_suite_config, read_episode_metadata
from adademo_lerobot.dataset.video import video_backend
from adademo_lerobot.loop.configs import PushConfig
from adademo_lerobot.loop.dataset_card import adademo_card_section, summarize_rounds
from adademo_lerobot.loop.expand import finish_stale_journals, unfinished_rounds

log = logging.getLogger(__name__)


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
    unfinished = unfinished_rounds(root)
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

    # Stock LeRobot must open what we publish; its video decoder chosen quietly (`dataset/video.py`).
    dataset = LeRobotDataset(cfg.repo_id, root=root, video_backend=video_backend())
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
        # The network, not the input: nothing was pushed, and the same command pushes once the hub answers.
        raise MachineError(
            f"cannot reach the hub at {constants.ENDPOINT}: {type(err).__name__}; check the network (or "
            "HF_ENDPOINT), then run the same command to push"
        ) from None

    url = f"{constants.ENDPOINT}/datasets/{cfg.repo_id}" + (f"/tree/{branch}" if branch else "")
    print(
        f"pushed {dataset.meta.total_episodes} episodes ({len(summarize_rounds(root, []))} rounds) "
        f"with the adademo card to {url}"
    )
    return url
