"""LeRobot's own human-in-the-loop data continues here: datasets written by stock `lerobot-rollout
--strategy.type=dagger` on the simulated robot (`adademo_sim`, the `adademo_scripted` teleoperator as the person,
a tiny ACT from stock `lerobot-record` + `lerobot-train`), its keys typed into a pseudo-terminal as a person types
them (space pauses the policy, tab starts and ends a correction, Esc stops). One dataset of each kind (corrections
only, and with the policy's own frames kept: `--strategy.record_autonomous=true`) is recorded per session and
copied per test: we read it, train on it, continue a round on it with adademo-record and report it.
"""

from __future__ import annotations

import json
import os
import pty
import select
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import (
    BIN,
    TINY_ACT_POLICY,
    assert_cli_error,
    file_digests,
    requires_rendering,
    run_cli,
    stock_tiny_train,
)

from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.interventions import imitation_units, intervention_flags
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.loop.report_costs import person_work
from adademo_lerobot.loop.train import policy_action_mask
from adademo_lerobot.samplers import frame_weights, make_sampling_scheme

SIM = ["--robot.type=adademo_sim", "--robot.tasks=reach-v3,push-v3", "--robot.image_size=32"]
TASK = "reach-v3"
RECIPES = Path(__file__).resolve().parents[1] / "recipes"


class Terminal:
    """A command whose stdin, stdout and stderr are a pseudo-terminal (where LeRobot's key listener reads keys
    when there is no display), and the keys a person types into it."""

    def __init__(self, argv: list[str]):
        self.fd, child = pty.openpty()
        # Without a display LeRobot reads keys from the terminal (with one, from the X server: not ours to type).
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        self.proc = subprocess.Popen(
            argv, stdin=child, stdout=child, stderr=child, env=env, start_new_session=True
        )
        os.close(child)
        self.output, self._unread = "", ""

    def _read(self, timeout: float) -> bool:
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return True
        try:
            data = os.read(self.fd, 65536).decode(errors="replace")
        except OSError:  # the command has ended
            return False
        self.output += data
        self._unread += data
        return bool(data)

    def wait_for(self, text: str, timeout: float = 300) -> None:
        deadline = time.time() + timeout
        while text not in self._unread:
            assert time.time() < deadline, f"no {text!r} from the command:\n{self.output[-3000:]}"
            assert self._read(0.1), f"the command ended before {text!r}:\n{self.output[-3000:]}"
        self._unread = self._unread[self._unread.index(text) + len(text) :]

    def run_for(self, seconds: float) -> None:
        end = time.time() + seconds
        while time.time() < end and self._read(0.05):
            pass

    def press(self, key: str) -> None:
        os.write(self.fd, key.encode())

    def finish(self, timeout: float = 300) -> int:
        deadline = time.time() + timeout
        while self._read(1.0) and self.proc.poll() is None:
            assert time.time() < deadline, self.output[-3000:]
        os.close(self.fd)
        return self.proc.wait(timeout=60)


SPACE, TAB, ESC = " ", "\t", "\x1b"  # LeRobot's DAgger keys: pause/resume, correction start/end, stop


def lerobot_rollout_dagger(root: Path, checkpoint: Path, record_autonomous: bool) -> Path:
    """Two corrections recorded by stock `lerobot-rollout --strategy.type=dagger`, keys typed as a person would."""
    name = f"rollout_{'all' if record_autonomous else 'corrections'}"
    term = Terminal(
        [
            str(BIN / "lerobot-rollout"),
            "--strategy.type=dagger",
            f"--strategy.record_autonomous={str(record_autonomous).lower()}",
            "--strategy.smooth_handover=false",  # the scripted teleop has no arm to slide to
            *SIM,
            f"--robot.task={TASK}",
            "--teleop.type=adademo_scripted",
            f"--policy.path={checkpoint}",
            f"--dataset.repo_id=local/{name}",
            f"--dataset.root={root}",
            f"--dataset.single_task={TASK}",
            "--dataset.num_episodes=2",
            "--dataset.push_to_hub=false",
            "--play_sounds=false",
            "--display_data=false",
        ]
    )
    term.wait_for("recording started")
    for n in range(2):
        term.run_for(1.5)  # the policy drives
        term.press(SPACE)
        term.wait_for("autonomous -> paused")
        term.press(TAB)
        term.wait_for("paused -> correcting")
        term.run_for(1.0)  # the person drives
        term.press(TAB)
        term.wait_for("correcting -> paused")
        if record_autonomous or n == 0:
            term.press(SPACE)
            term.wait_for("paused -> autonomous")
    if record_autonomous:  # it records until stopped; corrections-only stops after --dataset.num_episodes
        term.run_for(1.0)
        term.press(ESC)
    code = term.finish()
    assert code == 0, term.output[-3000:]
    return root


@pytest.fixture(scope="session")
def dagger(tmp_path_factory) -> dict:
    """A tiny ACT (stock lerobot-record + lerobot-train on the simulated robot) and two DAgger datasets recorded
    with it by stock lerobot-rollout: corrections only, and with the policy's frames (`all`)."""
    tmp = tmp_path_factory.mktemp("dagger")
    base = tmp / "base"
    run_cli(
        "lerobot-record",
        *SIM,
        f"--robot.task={TASK}",
        "--teleop.type=adademo_scripted",
        "--dataset.repo_id=local/robot",
        f"--dataset.root={base}",
        f"--dataset.single_task={TASK}",
        "--dataset.fps=80",
        "--dataset.num_episodes=2",
        "--dataset.episode_time_s=1",
        "--dataset.reset_time_s=0",
        "--dataset.push_to_hub=false",
        "--display_data=false",
        "--play_sounds=false",
    )
    checkpoint = stock_tiny_train(base, tmp / "train")
    return {
        "checkpoint": checkpoint,
        "corrections": lerobot_rollout_dagger(tmp / "rollout_corrections", checkpoint, False),
        "all": lerobot_rollout_dagger(tmp / "rollout_all", checkpoint, True),
    }


def copy_of(dagger: dict, kind: str, tmp_path: Path) -> Path:
    root = tmp_path / kind
    shutil.copytree(dagger[kind], root)
    return root


def stock_flags(root: Path) -> np.ndarray:
    """Every frame's `intervention` as stock LeRobot reads it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    table = LeRobotDataset("local/x", root=root, video_backend="pyav").hf_dataset.with_format(None)
    return np.array([bool(np.asarray(v).reshape(-1)[0]) for v in table["intervention"]])


@requires_rendering
@pytest.mark.parametrize("kind", ["corrections", "all"])
def test_a_dagger_dataset_reads_as_corrections_and_the_policys_frames(dagger, kind, tmp_path):
    root = copy_of(dagger, kind, tmp_path)
    before = file_digests(root)
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["features"]["intervention"]["dtype"] == "bool"  # what lerobot-rollout's DAgger writes
    flags = intervention_flags(root)
    np.testing.assert_array_equal(flags, stock_flags(root))
    eps = read_episode_metadata(root)
    assert (eps["adademo/round"] == 0).all()
    for index, ep in eps.iterrows():
        mine = flags[int(ep["dataset_from_index"]) : int(ep["dataset_to_index"])]
        if mine.any():  # a person intervened: a correction from the first frame the person drove
            assert ep["adademo/source"] == "correction" and ep["adademo/collector"] == "teleop"
            assert ep["adademo/start_step"] == int(np.argmax(mine))
        else:
            assert ep["adademo/source"] == "policy", index
    counted = person_work(root).set_index(["round", "task"]).loc[(0, TASK)]
    assert counted["person frames"] == flags.sum() > 0
    assert counted["person seconds"] == round(flags.sum() / info["fps"], 1)
    if kind == "corrections":  # each correction its own episode, every frame the person's
        assert flags.all() and len(eps) == 2 and counted["corrections"] == 2
        assert (eps["adademo/start_step"] == 0).all()
    else:  # one episode: the policy, two interventions, the policy again
        assert counted["corrections"] == 2 and counted["policy frames"] == (~flags).sum() > 0
        assert not flags[0] and eps["adademo/start_step"].iloc[0] > 0
    assert file_digests(root) == before  # reading changes nothing


@requires_rendering
def test_training_imitates_the_persons_frames_unless_asked(dagger, tmp_path):
    root = copy_of(dagger, "all", tmp_path)
    eps, flags = read_episode_metadata(root), intervention_flags(root)
    scheme = make_sampling_scheme("trajectory", 0.0, 1)
    person_only = frame_weights(scheme, imitation_units(root, eps, 0.0), len(flags))
    assert person_only[~flags].sum() == 0 and person_only[flags].min() > 0
    both = frame_weights(scheme, imitation_units(root, eps, 1.0), len(flags))
    assert both[~flags].min() > 0
    half = frame_weights(scheme, imitation_units(root, eps, 0.5), len(flags))
    assert 0 < half[~flags].sum() < both[~flags].sum()

    # The action chunk of the person's last frame before handing back: the policy's actions after it are no target.
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from torch.utils.data import default_collate

    fps = json.loads((root / "meta" / "info.json").read_text())["fps"]
    chunk = {"action": [i / fps for i in range(10)]}
    stock = LeRobotDataset("local/x", root=root, video_backend="pyav", delta_timestamps=chunk)
    handed_back = int(np.flatnonzero(flags[:-1] & ~flags[1:])[0])  # the person's frame before the policy's
    batch = default_collate([stock[handed_back]])
    policy_action_mask(stock, flags)(batch)
    assert batch["action_is_pad"][0].tolist() == [False] + [True] * 9

    out = tmp_path / "train"
    args = [
        "--dataset.repo_id=local/rollout_all",
        f"--dataset.root={root}",
        *TINY_ACT_POLICY,
        "--policy.pretrained_backbone_weights=null",
        "--batch_size=4",
        "--steps=2",
        "--save_freq=2",
    ]
    run_cli("adademo-train", *args, f"--output_dir={out}")
    info = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "adademo_train.json").read_text())
    assert info["autonomous_weight"] == 0.0
    assert_cli_error("adademo-train", *args, f"--output_dir={tmp_path / 'x'}", "--autonomous_weight=-1",
                     match="--autonomous_weight must be >= 0")  # fmt: skip


def record_args(root: Path, checkpoint: Path, *extra: str) -> list[str]:
    return [
        *SIM,
        "--teleop.type=adademo_scripted",
        f"--policy.path={checkpoint}",
        f"--dataset.repo_id=local/{root.name}",
        f"--dataset.root={root}",
        "--dataset.episode_time_s=3",
        "--strategy.target_successes=1",
        "--strategy.max_demos_per_task=1",
        *extra,
    ]


@requires_rendering
@pytest.mark.parametrize(
    "kind,demo_start",
    [("corrections", "takeover"), pytest.param("all", "initial", marks=pytest.mark.slow)],
    ids=["corrections", "all"],
)
def test_adademo_record_continues_a_dagger_dataset(dagger, kind, demo_start, tmp_path):
    """The issue's crash: adademo-record on LeRobot's DAgger data now adds the person's episodes, each frame
    `intervention=True`, keeps the DAgger episodes' reading, and stock LeRobot opens and trains on the result."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = copy_of(dagger, kind, tmp_path)
    before = read_episode_metadata(root)
    takeover = (
        ["--demo_start=takeover", "--teleop.takeover_threshold=0.5"] if demo_start == "takeover" else []
    )
    done = run_cli("adademo-record", *record_args(root, dagger["checkpoint"], *takeover))
    assert "round 1:" in done.stdout
    if demo_start == "takeover":  # what the person added, by kind
        assert "correction" in done.stdout.split("round 1:")[1].split(" added to ")[0]
    check_dataset_integrity(root)
    eps = read_episode_metadata(root)
    old, new = eps.loc[before.index], eps[eps["adademo/round"] == 1]
    assert len(new) >= 1
    cols = ["adademo/source", "adademo/start_step", "adademo/collector", "adademo/round"]
    pd.testing.assert_frame_equal(old[cols], before[cols])  # now stored as columns: the same reading
    flags = intervention_flags(root)
    np.testing.assert_array_equal(flags, stock_flags(root))
    for _, ep in new.iterrows():  # the person's frames
        assert flags[int(ep["dataset_from_index"]) : int(ep["dataset_to_index"])].all()
    if demo_start == "takeover":
        assert set(new["adademo/source"]) == {"correction"}
    assert LeRobotDataset("local/x", root=root, video_backend="pyav").meta.total_episodes == len(eps)
    assert not (
        root / "images"
    ).exists()  # as stock lerobot-record leaves its datasets: no empty frame folders

    work = person_work(root).set_index("round")
    assert work.loc[1, "person frames"] == int(new["length"].sum())
    assert work["person frames"].sum() == flags.sum()
    report = run_cli("adademo-report", f"--dataset_root={root}")
    assert "person frames" in report.stdout and f"| 1 | {TASK} |" in report.stdout

    run_cli(
        "lerobot-train",
        f"--dataset.repo_id=local/{root.name}",
        f"--dataset.root={root}",
        *TINY_ACT_POLICY,
        "--policy.pretrained_backbone_weights=null",
        "--policy.push_to_hub=false",
        "--batch_size=4",
        "--steps=1",
        "--save_freq=1",
        f"--output_dir={tmp_path / 'stock'}",
        "--num_workers=0",
        "--env_eval_freq=0",
        "--wandb.enable=false",
    )


@requires_rendering
def test_a_feature_adademo_does_not_write_is_refused_before_the_first_episode(dagger, tmp_path):
    from lerobot.datasets.dataset_tools import add_features
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    source = LeRobotDataset("local/rollout_corrections", root=dagger["corrections"], video_backend="pyav")
    root = tmp_path / "rollout_rewarded"
    add_features(
        source,
        {"reward": (np.zeros(source.meta.total_frames, np.float32), {"dtype": "float32", "shape": [1], "names": None})},
        output_dir=root,
        repo_id="local/rollout_rewarded",
    )  # fmt: skip
    before = file_digests(root)
    assert_cli_error(
        "adademo-record",
        *record_args(root, dagger["checkpoint"]),
        match="reward that adademo-record does not record",
    )
    assert file_digests(root) == before  # refused before the first episode: nothing recorded, nothing changed


def test_our_simulated_collection_refuses_a_feature_it_does_not_write(reach_push_dataset, tmp_path):
    """The same rule for every writer: adademo-collect refuses a dataset with a feature it does not write, before
    writing anything (LeRobot's writer would refuse each of its frames)."""
    from lerobot.datasets.dataset_tools import add_features
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    source = LeRobotDataset("local/demo", root=reach_push_dataset)
    rewarded = tmp_path / "rewarded"
    add_features(
        source,
        {
            "reward": (
                np.zeros((source.meta.total_frames, 1), np.float32),
                {"dtype": "float32", "shape": [1], "names": None},
            )
        },
        output_dir=rewarded,
        repo_id="local/rewarded",
    )
    before = file_digests(rewarded)
    assert_cli_error(
        "adademo-collect",
        "--suite.type=metaworld",
        "--suite.tasks=reach-v3,push-v3",
        "--dataset.repo_id=local/rewarded",
        f"--dataset.root={rewarded}",
        "--episodes_per_task=4",
        "--resume=true",
        match="reward that adademo does not record",
    )
    assert file_digests(rewarded) == before


def run_args(root: Path, checkpoint: Path, run_dir: Path) -> list[str]:
    return [
        f"--config_path={RECIPES / 'continue_from_checkpoint.yaml'}",
        f"--run_dir={run_dir}",
        f"--dataset.repo_id=local/{root.name}",
        f"--dataset.root={root}",
        f"--policy.path={checkpoint}",
        "--strategy.budget=[2]",
        "--strategy.max_demos_per_task=[2]",
        "--train.finetune_steps=4",
        "--train.save_freq=4",
        "--train.batch_size=4",
        "--eval.episodes_per_task=2",
        "--eval.batch_size=2",
        "--suite.max_episode_steps=60",  # a suite flag without --suite.tasks: the rest comes from the dataset
        "--torch_threads=1",
    ]


@pytest.mark.slow  # adademo-record continuing the same DAgger data runs by default
@requires_rendering
def test_adademo_run_continues_a_dagger_dataset_of_the_simulated_robot(dagger, tmp_path):
    """Two rounds of adademo-run on lerobot-rollout's DAgger data from the simulated robot: the dataset is a
    robot view of a MetaWorld suite (its camera, its motor names, no environment_state), the rounds' episodes
    fit beside the DAgger ones (each frame `intervention=True`), the DAgger episodes keep their reading, the
    user's folder is untouched, and stock LeRobot opens the result."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = copy_of(dagger, "all", tmp_path)
    before, digests = read_episode_metadata(root), file_digests(root)
    run_cli("adademo-run", *run_args(root, dagger["checkpoint"], tmp_path / "run"))
    grown = tmp_path / "run" / "dataset"
    check_dataset_integrity(grown)
    suite = json.loads((grown / "meta" / "adademo" / "suite.json").read_text())
    assert (suite["view"], suite["tasks"], suite["camera"], suite["image_size"]) == (
        "robot",
        TASK,
        "corner2",
        32,
    )
    assert suite["max_episode_steps"] == 60
    info = json.loads((grown / "meta" / "info.json").read_text())
    assert "observation.environment_state" not in info["features"]
    assert info["features"]["observation.state"]["names"] == ["x.pos", "y.pos", "z.pos", "gripper.pos"]
    eps = read_episode_metadata(grown)
    cols = ["adademo/source", "adademo/start_step", "adademo/collector", "adademo/round"]
    pd.testing.assert_frame_equal(eps.loc[before.index, cols], before[cols])
    new = eps.drop(before.index)
    assert sorted(set(new["adademo/round"])) == [1, 2]  # both rounds added demonstrations
    assert (new["adademo/seed"] >= 0).all() and (new["task"] == TASK).all()
    flags = intervention_flags(grown)
    np.testing.assert_array_equal(flags, stock_flags(grown))
    for _, ep in new.iterrows():
        assert flags[int(ep["dataset_from_index"]) : int(ep["dataset_to_index"])].all()
    assert not flags[: int(before["dataset_to_index"].max())].all()  # the policy's own DAgger frames, still
    assert LeRobotDataset("local/x", root=grown, video_backend="pyav").meta.total_episodes == len(eps)
    assert not (grown / "images").exists()
    assert file_digests(root) == digests


@requires_rendering
def test_adademo_run_points_a_real_robots_dataset_to_adademo_record(dagger, tmp_path):
    """adademo-run evaluates in simulation: a dataset recorded on a real robot (here the DAgger dataset with the
    robot type an SO-101 would write) is refused in one line that says where it grows instead, with or without
    suite flags, and nothing is written."""
    root = copy_of(dagger, "corrections", tmp_path)
    info_path = root / "meta" / "info.json"
    info_path.write_text(json.dumps(json.loads(info_path.read_text()) | {"robot_type": "so101_follower"}))
    before = file_digests(root)
    args = run_args(root, dagger["checkpoint"], tmp_path / "run")
    assert_cli_error("adademo-run", *args, match="recorded on a robot (so101_follower)?")
    assert_cli_error(
        "adademo-run",
        *args,
        "--suite.tasks=reach-v3",
        match="one recorded on a robot grows with adademo-record",
    )
    assert not (tmp_path / "run").exists() and file_digests(root) == before
