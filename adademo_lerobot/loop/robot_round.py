"""`adademo-record`'s round on a robot: the connected robot, teleoperator, policy and person (`Session`: a short
control loop of LeRobot's pieces), and the round context the strategy runs on them (`PersonRound`)."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from adademo_lerobot.core.episodes import Demonstration, TaskRoundRecord
from adademo_lerobot.core.threads import set_torch_threads
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.layout import ADADEMO_DIR
from adademo_lerobot.dataset.ledger import RoundJournal
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.strategies.bookkeeping import JournaledRound, committed_demos, demo_entry
from adademo_lerobot.strategies.round_context import Outcome

if TYPE_CHECKING:
    from adademo_lerobot.loop.configs import RecordConfig

SOURCE = "human"


class Session:
    """The connected robot, teleoperator, policy and person of one round, and its journal."""

    def __init__(self, cfg: RecordConfig, robot, teleop, person, features: dict, round_index: int):
        from lerobot.common.control_utils import predict_action
        from lerobot.policies.utils import make_robot_action
        from lerobot.utils.constants import ACTION, OBS_STR
        from lerobot.utils.feature_utils import build_dataset_frame

        from adademo_lerobot.evaluation.policy import load_policy

        self.cfg, self.robot, self.teleop, self.person = cfg, robot, teleop, person
        self.features, self.round_index = features, round_index
        self.root = Path(cfg.dataset.root)
        self.dataset = DemoDataset.open_recorded(cfg.dataset.repo_id, self.root)
        self.journal = RoundJournal(self.root, round_index)
        set_torch_threads(cfg.torch_threads)
        self.loaded = load_policy(cfg.policy.path, cfg.device)
        self.fps = read_info(self.root)["fps"]
        self.max_steps = max(1, round(cfg.dataset.episode_time_s * self.fps))
        self.simulated = getattr(robot, "simulated", False)
        self.state_names = features[f"{OBS_STR}.state"]["names"]
        self.cameras = [
            k.removeprefix(f"{OBS_STR}.images.") for k in features if k.startswith(f"{OBS_STR}.images.")
        ]
        self._predict, self._make_action, self._frame = predict_action, make_robot_action, build_dataset_frame
        self._obs, self._action = OBS_STR, ACTION

    # -- one step and one episode ----------------------------------------------------------------------------
    def _pace(self, started: float) -> None:
        if not self.simulated:  # a real robot runs at the dataset's rate; a simulated one as fast as it can
            from lerobot.utils.robot_utils import precise_sleep

            precise_sleep(max(0.0, 1 / self.fps - (time.perf_counter() - started)))

    def _joints(self, obs: dict) -> list[float]:
        return [float(obs[name]) for name in self.state_names]

    def _save_first_frames(self, obs: dict, task: str, seed: int) -> dict[str, str]:
        from PIL import Image

        paths = {}
        folder = self.root / ADADEMO_DIR / "episode_starts" / f"round-{self.round_index:03d}"
        for camera in self.cameras:
            rel = folder.relative_to(self.root) / f"{slug(task)}-{seed}-{camera}.png"
            (self.root / rel).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.asarray(obs[camera], dtype=np.uint8)).save(self.root / rel)
            paths[camera] = str(rel)
        return paths

    def policy_episode(self, task: str, seed: int) -> dict:
        """A new scene, the policy until the person (or the clock) ends it, then the person's verdict."""
        loaded = self.loaded
        if self.simulated:
            self.robot.reset_scene(seed)
        else:
            self.person.ready(f"{task}: set up a new scene for the policy (episode {seed}), then press n")
        for part in (loaded.policy, loaded.preprocessor, loaded.postprocessor):
            part.reset()
        import torch

        device = torch.device(self.cfg.device)
        start, first, steps, taken_over = time.perf_counter(), None, 0, None
        may_take_over = self.cfg.demo_start == "takeover"
        while steps < self.max_steps:
            step_start = time.perf_counter()
            obs = self.robot.get_observation()
            if first is None:
                first = obs
            if may_take_over and self.person.takes_over():
                taken_over = obs  # the person has the robot from here on: the policy failed
                break
            frame = self._frame(self.features, obs, self._obs)
            values = self._predict(
                frame, loaded.policy, device, loaded.preprocessor, loaded.postprocessor, False, task,
                self.robot.robot_type,
            )  # fmt: skip
            self.robot.send_action(self._make_action(values, self.features))
            steps += 1
            if self.person.episode_over():
                break
            self._pace(step_start)
        entry = {
            "type": "eval",
            "task": task,
            "seed": seed,
            "success": taken_over is None and bool(self.person.judge(task)),
            "steps": steps,
            "initial_state": self._joints(first),
            "first_frames": self._save_first_frames(first, task, seed),
            "seconds": round(time.perf_counter() - start, 3),
        }
        if taken_over is not None:
            entry |= {
                "takeover_step": steps,
                "takeover_rule": "person",
                "takeover_state": self._joints(taken_over),
            }
        return entry

    def _teleoperate(self) -> tuple[list[dict], dict]:
        """The person drives the robot from where it is until they end the episode: (frames, first observation)."""
        frames_out, first = [], None
        while len(frames_out) < self.max_steps:
            step_start = time.perf_counter()
            obs = self.robot.get_observation()
            first = first or obs
            sent = self.robot.send_action(self.teleop.get_action())
            frames_out.append(
                {
                    **self._frame(self.features, obs, self._obs),
                    **self._frame(self.features, sent, self._action),
                }
            )
            if self.person.episode_over():
                break
            self._pace(step_start)
        return frames_out, first

    def correction(self, task: str, failed: dict) -> tuple[Demonstration | None, float]:
        """The person's correction from where they took over the policy (the robot is still there): one attempt,
        since the scene cannot be put back mid-episode; a rejected one leaves the failure unanswered."""
        start = time.perf_counter()
        frames_out, _ = self._teleoperate()
        if not self.person.keep_demo(task):
            return None, time.perf_counter() - start
        demo = Demonstration(
            task,
            np.asarray(failed["initial_state"], np.float64),
            failed["seed"],
            frames_out,
            1,
            start_step=failed["takeover_step"],
            start_state=np.asarray(failed["takeover_state"], np.float64),
            is_correction=True,
        )
        return demo, time.perf_counter() - start

    def demonstration(
        self, task: str, failed: dict | None, seed: int
    ) -> tuple[Demonstration | None, int, float]:
        """The person's demonstration from the failed episode's start, or (`failed` None: a fresh initial state,
        no policy episode before it) from a new scene: (demo or None after every attempt gave none, attempts,
        seconds)."""
        start = time.perf_counter()
        for attempt in range(1, self.cfg.max_attempts + 1):
            if self.simulated:
                self.robot.reset_scene(seed)
            elif failed is None:
                self.person.ready(
                    f"{task}: set up a new scene (demonstration {seed}, no policy episode before it), press n, "
                    "then teleoperate the task; press n when done"
                )
            else:
                frames = ", ".join(str(self.root / p) for p in failed["first_frames"].values())
                joints = ", ".join(
                    f"{n}={v:.3g}" for n, v in zip(self.state_names, failed["initial_state"], strict=True)
                )
                self.person.ready(
                    f"{task}: put the scene back as it was when episode {seed} started "
                    f"({'first frame: ' + frames + '; ' if frames else ''}joints: {joints}), press n, then "
                    "teleoperate the task; press n when done"
                )
            frames_out, first = self._teleoperate()
            if self.person.keep_demo(task):
                demo = Demonstration(task, np.asarray(self._joints(first)), seed, frames_out, attempt)
                return demo, attempt, time.perf_counter() - start
        return None, self.cfg.max_attempts, time.perf_counter() - start

    # -- between episodes -------------------------------------------------------------------------------------
    def select_task(self, task: str) -> None:
        """The next episodes are of `task`: a simulated robot switches scenes, a person sets its scene up."""
        if hasattr(self.robot, "select_task"):
            self.robot.select_task(task)
        else:
            self.person.ready(f"next task: {task!r}: set up its scene, then press n")

    def append(self, demo: Demonstration) -> None:
        """A demonstration (or correction) into the dataset, with its provenance, in one transaction."""
        self.dataset.append_recorded(
            self.robot.robot_type, [demo], self.round_index, SOURCE, self.cfg.teleop.type
        )


class PersonRound(JournaledRound):
    """Algorithm 1's round context (`algorithm.InnerLoop`, as `RoundContext` is in a simulated round) with a person
    and a robot behind it. Evaluating a state is a policy episode the person judges, or takes over (the correction is
    recorded at once, while the robot is where the person took over); a demonstration is the person's, from the
    failed episode's start, or that correction, or (a seed the round never evaluated: a strategy paying for its
    rollouts buys demonstrations from fresh initial states) from a new scene. Its books are the simulated
    round's (`JournaledRound`): everything is journaled first, so after a stop the strategy runs again over the
    same states and reuses what was done."""

    batch_size = 1  # one robot, one episode at a time
    seed: int
    round_index: int
    tasks: list[str]  # --tasks, in order
    root: Path

    def __init__(self, session: Session, tasks: list[str]):
        self.session, self.journal = session, session.journal
        self.seed, self.round_index = session.cfg.seed, session.round_index
        self.tasks, self.root = tasks, session.root
        self.policy_path = str(session.cfg.policy.path)
        self._lock = threading.RLock()
        self._committed = committed_demos(self.root, self.round_index)
        self._corrections: dict[tuple[str, int], tuple[Demonstration | None, float]] = {}
        self._task: str | None = None  # the task whose scene is up

    @property
    def corrects_failures(self) -> bool:
        return self.session.cfg.demo_start == "takeover"

    def _use(self, task: str) -> None:
        if task != self._task:
            self.session.select_task(task)
            self._task = task

    def run_tasks(self, work) -> list[TaskRoundRecord]:
        return [work(task) for task in self.tasks]

    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        outcomes = []
        for seed in seeds:
            entry = self.journal.evaluations(task).get(seed)
            if entry is None:
                self._use(task)
                entry = self.session.policy_episode(task, seed)
                self._journal(entry)  # first: a stop during the correction leaves a failure to answer
                if "takeover_step" in entry:
                    self._corrections[(task, seed)] = self.session.correction(task, entry)
            outcomes.append(Outcome(seed, bool(entry["success"])))
        return outcomes

    def ask_expert(self, task: str, seeds: list[int]) -> None:
        """A person does one demonstration at a time, when asked (`collect_demo`)."""

    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        reused = self.reuse_answer(task, seed, record)  # answered before a stop
        if reused is not None:
            return reused
        failed = self.journal.evaluations(task).get(seed)  # None: a fresh initial state (a new scene)
        if (task, seed) in self._corrections:
            (demo, seconds), attempts = self._corrections.pop((task, seed)), 1
        else:  # from the episode's start (a correction a stop interrupted too: the robot has moved since)
            self._use(task)
            demo, attempts, seconds = self.session.demonstration(task, failed, seed)
        if demo is None:
            entry = {
                "type": "expert_failure",
                "task": task,
                "seed": int(seed),
                "attempts": attempts,
                "initial_state": failed["initial_state"] if failed else None,
            }
            return self.store_answer(task, entry, record)
        entry = {**demo_entry(task, seed, demo, len(demo.frames)), "seconds": round(seconds, 3)}
        return self.store_answer(task, entry, record, lambda: self.session.append(demo))

    def progress(self, task: str, record: TaskRoundRecord) -> None:
        pass

    def with_costs(self, record: TaskRoundRecord) -> TaskRoundRecord:
        """The ledger's figures the strategy does not count: every policy episode run and the person's time."""
        self.evaluation_cost(record.task, record)
        policy_s = sum(e.get("seconds", 0.0) for e in self.journal.evaluations(record.task).values())
        demo_s = sum(d.get("seconds", 0.0) for d in self.journal.demos(record.task).values())
        record.wall_seconds = round(policy_s + demo_s, 1)
        record.extra = {
            **record.extra,
            "person_seconds": {"policy_episodes": round(policy_s, 1), "demonstrations": round(demo_s, 1)},
        }
        # The expert is a person: which teleoperator and robot they demonstrated with.
        record.collector = {
            "type": "person",
            "teleop": self.session.cfg.teleop.type,
            "robot": self.session.robot.robot_type,
        }
        return record


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")[:60] or "task"
