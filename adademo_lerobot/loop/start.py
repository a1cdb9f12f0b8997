"""Where `adademo-run` starts when the user already has a dataset and, optionally, a trained policy.

    --dataset.repo_id=user/name [--dataset.root=FOLDER] [--dataset.revision=REV] [--dataset.copy=true]
    --policy.path=CKPT_FOLDER_OR_HUB_ID [--policy.revision=REV]

A dataset without `--dataset.root` comes from the hub through LeRobot's own download (into `HF_LEROBOT_HOME`, as
stock LeRobot does); a hub checkpoint through `huggingface_hub.snapshot_download`. Everything is checked before
the run folder is made: the dataset opens and is whole, its features fit the suite (its `meta/adademo/suite.json`
or the suite flags), the checkpoint reads and writes those features and is of the recipe's policy type. The run
then expands a copy under the run folder (the original stays byte-for-byte unchanged), or, with
`--dataset.copy=false`, the dataset itself.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import atomic_write_text
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.features import check_features_match
from adademo_lerobot.dataset.interventions import check_episode_stats
from adademo_lerobot.dataset.layout import SUITE_FILE
from adademo_lerobot.dataset.metadata import (
    check_same_suite,
    has_dataset,
    read_info,
    rebuild_suite_config,
    try_load_suite_config,
)
from adademo_lerobot.dataset.store import recover_unless_in_use
from adademo_lerobot.loop.push import is_hub_repo_id
from adademo_lerobot.suites import SuiteConfig, make_suite

log = logging.getLogger(__name__)


@dataclass
class StartDatasetArgs:
    # Start from this LeRobot dataset (round-0 collection is skipped): a hub repo id, downloaded into
    # HF_LEROBOT_HOME as stock LeRobot does, or any id with --dataset.root=FOLDER for a local dataset.
    repo_id: str | None = None
    root: str | None = None
    # Hub revision (branch, tag or commit); default: LeRobot's (the dataset-format tag).
    revision: str | None = None
    # Expand a copy under the run folder, leaving the original unchanged; false expands the dataset in place.
    copy: bool = True


@dataclass
class StartPolicyArgs:
    # Start from this checkpoint (round-0 training is skipped): a `.../pretrained_model` folder or a hub repo id.
    path: str | None = None
    # Hub revision of the checkpoint (branch, tag or commit).
    revision: str | None = None


def _hub_call(what: str, repo_id: str, revision: str | None, fn):
    """Call `fn()` and turn the hub's errors into one line that says what to check."""
    import httpx
    from huggingface_hub import constants
    from huggingface_hub.errors import (
        HfHubHTTPError,
        LocalEntryNotFoundError,
        RepositoryNotFoundError,
        RevisionNotFoundError,
    )

    where = f"the hub at {constants.ENDPOINT}"
    try:
        return fn()
    except RevisionNotFoundError:
        raise AdaDemoError(f"{what} {repo_id} has no revision {revision!r} on {where}") from None
    except RepositoryNotFoundError:
        raise AdaDemoError(
            f"{what} {repo_id} was not found on {where} (check the id and your token; a local folder needs "
            f"{'--dataset.root' if what == 'dataset' else 'a path that exists'})"
        ) from None
    except (LocalEntryNotFoundError, httpx.TransportError, ConnectionError) as err:
        raise AdaDemoError(f"cannot download {what} {repo_id} from {where}: {type(err).__name__}") from None
    except HfHubHTTPError as err:
        raise AdaDemoError(
            f"downloading {what} {repo_id} from {where} failed: {str(err).splitlines()[0]}"
        ) from None


def locate_dataset(args: StartDatasetArgs) -> tuple[Path, str | None]:
    """The dataset's folder (downloaded first for a hub id) and, for a hub dataset, the commit it resolved to."""
    if args.root is not None:
        root = Path(args.root).expanduser()
        if not has_dataset(root):
            raise AdaDemoError(f"no LeRobot dataset at --dataset.root={root} (missing meta/info.json)")
        return root.resolve(), None
    if not is_hub_repo_id(args.repo_id):
        raise AdaDemoError(
            f"--dataset.repo_id={args.repo_id!r} is not a hub id (user/name); for a local dataset also pass "
            "--dataset.root=FOLDER"
        )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from adademo_lerobot.dataset.video import video_backend

    def download():
        try:
            return LeRobotDataset(args.repo_id, revision=args.revision, video_backend=video_backend())
        except RuntimeError as err:  # LeRobot: no dataset-format version tag on the repo
            raise AdaDemoError(
                f"dataset {args.repo_id}: {' '.join(str(err).split())[:300]} (pass --dataset.revision=main to "
                "take the latest commit)"
            ) from None

    dataset = _hub_call("dataset", args.repo_id, args.revision, download)
    from huggingface_hub import HfApi

    info = _hub_call(
        "dataset",
        args.repo_id,
        dataset.revision,
        lambda: HfApi().dataset_info(args.repo_id, revision=dataset.revision),
    )
    return Path(dataset.root).resolve(), info.sha


def locate_checkpoint(args: StartPolicyArgs) -> tuple[Path, str | None]:
    """The checkpoint's folder (downloaded first for a hub id) and, for a hub checkpoint, its commit."""
    path = Path(args.path).expanduser()
    if path.exists():
        return path.resolve(), None
    if not is_hub_repo_id(args.path):
        raise AdaDemoError(f"no checkpoint at --policy.path={args.path} (no such folder, and not a hub id)")
    from huggingface_hub import HfApi, snapshot_download

    folder = _hub_call(
        "checkpoint", args.path, args.revision, lambda: snapshot_download(args.path, revision=args.revision)
    )
    info = _hub_call(
        "checkpoint", args.path, args.revision, lambda: HfApi().model_info(args.path, revision=args.revision)
    )
    return Path(folder), info.sha


def choose_suite(root: Path, requested: SuiteConfig, requested_is_default: bool) -> SuiteConfig:
    """The dataset's suite (its suite.json, or rebuilt from LeRobot's files, with what suite flags without
    --suite.tasks change), or the suite flags for a dataset that says nothing; suite flags that contradict the
    dataset's suite.json are refused."""
    stored = try_load_suite_config(root) if (root / SUITE_FILE).exists() else None
    if stored is not None:
        if not requested_is_default:
            check_same_suite(stored, requested)
        return stored
    if not requested_is_default and requested.tasks:
        return requested
    try:
        rebuilt = rebuild_suite_config(root)
    except AdaDemoError:
        info = read_info(root)
        if "observation.environment_state" not in info.get("features", {}):
            raise AdaDemoError(
                f"{root} names no simulation suite and has no observation.environment_state: recorded on a robot "
                f"({info.get('robot_type') or 'robot type not recorded'})? adademo-run evaluates every round in "
                "simulation; grow a robot's dataset with adademo-record and train with adademo-train "
                "(docs/robots.md), or pass the suite it was recorded in: --suite.type=... --suite.tasks=..."
            ) from None
        return requested  # the feature check below says what does not fit
    return rebuilt if requested_is_default else flags_over(rebuilt, requested)


def flags_over(rebuilt: SuiteConfig, requested: SuiteConfig) -> SuiteConfig:
    """The rebuilt suite with what the user's suite flags set (e.g. --suite.max_episode_steps without tasks)."""
    if type(requested) is not type(rebuilt):
        return requested  # another family: the feature check says what does not fit
    default = type(requested)()
    changed = {f.name: getattr(requested, f.name) for f in dataclasses.fields(requested)}
    changed = {k: v for k, v in changed.items() if v != getattr(default, k)}
    return dataclasses.replace(rebuilt, **changed)


def file_digests(root: Path) -> dict[str, str]:
    """sha256 of every file under `root` (symlinks followed), by relative path."""
    digests = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        with open(path, "rb") as f:
            digests[str(path.relative_to(root))] = hashlib.file_digest(f, "sha256").hexdigest()
    return digests


def combined_digest(digests: dict[str, str]) -> str:
    return hashlib.sha256(json.dumps(digests, sort_keys=True).encode()).hexdigest()


@dataclass
class Start:
    """A checked starting point: where the dataset is, its suite, and the checkpoint (or None)."""

    source_root: Path
    dataset_commit: str | None
    suite_config: SuiteConfig
    checkpoint: Path | None
    checkpoint_commit: str | None
    policy_type: str | None

    def origin(self, dataset: StartDatasetArgs, policy: StartPolicyArgs) -> dict:
        return {
            "dataset": {
                "repo_id": dataset.repo_id,
                "root": str(self.source_root),
                "revision": dataset.revision,
                "commit": self.dataset_commit,
                "copy": dataset.copy,
            },
            "policy": None
            if self.checkpoint is None
            else {
                "path": policy.path,
                "folder": str(self.checkpoint),
                "revision": policy.revision,
                "commit": self.checkpoint_commit,
                "type": self.policy_type,
            },
        }


def check_start(
    dataset: StartDatasetArgs,
    policy: StartPolicyArgs,
    requested_suite: SuiteConfig,
    requested_is_default: bool,
    recipe_policy=None,
    finetune: bool = False,
) -> Start:
    """Resolve and check the starting dataset and checkpoint; writes nothing outside the download caches."""
    from adademo_lerobot.dataset.features import dataset_features
    from adademo_lerobot.evaluation.policy import check_policy

    if policy.revision is not None and (policy.path is None or Path(policy.path).expanduser().exists()):
        raise AdaDemoError(
            f"--policy.revision={policy.revision} picks a revision of a hub checkpoint (--policy.path=USER/NAME); "
            + ("a local folder has none: drop it" if policy.path else "give --policy.path too")
        )
    if dataset.revision is not None and dataset.root is not None:
        raise AdaDemoError(
            f"--dataset.revision={dataset.revision} picks a revision of a hub dataset; with --dataset.root the "
            "local folder is used as it is: drop one"
        )
    root, dataset_commit = locate_dataset(dataset)
    # A write a kill left half-done is rolled back before the dataset is judged damaged.
    recover_unless_in_use(root, "adademo-run")
    check_dataset_integrity(root)
    check_episode_stats(root)  # the run appends to it (or its copy): refused before anything is copied
    suite_config = choose_suite(root, requested_suite, requested_is_default)
    suite = make_suite(suite_config)
    check_features_match(read_info(root).get("features", {}), suite, f"dataset {dataset.repo_id}")
    if not dataset.copy and dataset.root is None:
        raise AdaDemoError(
            "--dataset.copy=false expands a local dataset in place; a hub dataset lives in LeRobot's download "
            "cache: pass --dataset.root=FOLDER (e.g. after `hf download`), or keep --dataset.copy=true"
        )
    checkpoint = checkpoint_commit = policy_type = None
    if policy.path is not None:
        checkpoint, checkpoint_commit = locate_checkpoint(policy)
        checkpoint_config = check_policy(checkpoint, dataset_features(suite))
        policy_type = checkpoint_config.type
        if recipe_policy is not None and policy_type != recipe_policy.type:
            raise AdaDemoError(
                f"--policy.path holds a {policy_type} policy but the recipe trains {recipe_policy.type}: use a "
                f"recipe for {policy_type} (or --train.policy.type={policy_type}), or another checkpoint"
            )
        if recipe_policy is not None and finetune:
            check_recipe_policy_is_the_checkpoints(recipe_policy, checkpoint_config)
    return Start(root, dataset_commit, suite_config, checkpoint, checkpoint_commit, policy_type)


# Policy fields that say where and how a policy runs or is stored, not what it is.
NOT_ARCHITECTURE = {
    "device",
    "push_to_hub",
    "repo_id",
    "pretrained_path",
    "input_features",
    "output_features",
}


def check_recipe_policy_is_the_checkpoints(recipe_policy, checkpoint_config) -> None:
    """With --train.mode=finetune every round starts from the checkpoint, so the recipe's `train.policy` fields
    cannot take effect: refuse those that differ from the checkpoint's rather than ignore them."""
    import dataclasses

    defaults = type(recipe_policy)()
    for f in dataclasses.fields(recipe_policy):
        value = getattr(recipe_policy, f.name)
        if f.name in NOT_ARCHITECTURE or value == getattr(defaults, f.name):
            continue
        if value != getattr(checkpoint_config, f.name, None):
            raise AdaDemoError(
                f"--train.policy.{f.name}={value} differs from the checkpoint's "
                f"{f.name}={getattr(checkpoint_config, f.name, None)} and fine-tuning (--train.mode=finetune) "
                "keeps the checkpoint's: drop the flag (or the recipe's train.policy), or use --train.mode=scratch"
            )


def prepare_dataset(start: Start, copy: bool, run_dataset: Path) -> tuple[Path, dict[str, str]]:
    """The folder the run expands: a copy at `run_dataset` (made whole, then renamed into place) or, without
    copy, the dataset itself. Returns it with the original's file digests."""
    digests = file_digests(start.source_root)
    if not copy or start.source_root == run_dataset.resolve():
        if not os.access(start.source_root, os.W_OK):
            raise AdaDemoError(f"dataset root {start.source_root} is not writable (--dataset.copy=false)")
        log.info(
            "expanding %s in place (--dataset.copy=false): new episodes are added to it", start.source_root
        )
        root = start.source_root
    else:
        tmp = run_dataset.with_name(f".{run_dataset.name}.copying")
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.copytree(start.source_root, tmp, ignore=shutil.ignore_patterns(".cache"))
        # A copy an interrupted invocation renamed into place before its start stage was recorded: replaced whole.
        shutil.rmtree(run_dataset, ignore_errors=True)
        os.replace(tmp, run_dataset)
        log.info(
            "copied %s to %s (%d files); the original stays unchanged",
            start.source_root,
            run_dataset,
            len(digests),
        )
        root = run_dataset
    if not (
        root / SUITE_FILE
    ).exists():  # a dataset recorded elsewhere: say from now on how to build its envs
        atomic_write_text(root / SUITE_FILE, start.suite_config.to_json())
    return root, digests
