"""`adademo-record`: one AdaDemo round on a robot, with a person in Algorithm 1's inner loop.

    adademo-record --robot.type=so101_follower --robot.port=/dev/ttyACM0 --robot.cameras=... \\
        --teleop.type=so101_leader --teleop.port=/dev/ttyACM1 --policy.path=CKPT \\
        --dataset.repo_id=USER/NAME --dataset.root=FOLDER \\
        --strategy.type=adademo --strategy.target_successes=5 --strategy.max_demos_per_task=10

The strategy is adademo-expand's, from the same flags with the same defaults (`--strategy.*`): the round runs the
strategy's own `expand`, with a person-backed round context (`PersonRound`) in place of the simulated one. With
`--strategy.type=adademo`, for every task of the dataset (or `--tasks`), until E successes or CAP demonstrations:
  1. the person sets up a new scene and the policy runs an episode (the person ends it early with n);
  2. the person marks it a success (s) or a failure (f);
  3. after a failure the person puts the scene back as it was when that episode started (its first camera frame is
     saved to look at, its initial joint positions are printed) and teleoperates a demonstration from there, which
     is appended to the dataset with its provenance (n keeps it, r records it again).
With `--demo_start=takeover` the person may instead take over while the policy goes wrong (t, or the
teleoperator's intervention event): the policy episode counts as a failure and the person's correction is recorded
from that moment, with the robot's joint positions then as its start state (no scene to set up again). A failure
the person did not take over is answered as above.
With `--strategy.type=budgeted --strategy.budget=B` the same steps spend exactly B demonstrations, the task
furthest below its share of the budget going next. Strategies that also demonstrate from fresh initial states
(uniform, task_only, budgeted paying for rollouts) need a simulated round and are refused.
Before the first episode, a plan from each task's latest success rate (adademo: the paper's N_k = E/SR_k - E;
budgeted: the budget's first split) says how many demonstrations each task will likely need and how long that takes
at the dataset's episode length (principle A).

Keys (LeRobot's key listener, as in lerobot-record): n or Right = next, r or Left = redo, s = success,
f = failure, t = take over (with --demo_start=takeover), q or Esc = stop. A simulated robot (`adademo_sim`) sets its scenes itself, and a teleoperator that
reports LeRobot's teleop events (`adademo_scripted`) answers for the person.

The loop is the strategy's own (adademo: `algorithm.collect_on_failed_states`, as adademo-expand runs it) with a
person-backed round context (`PersonRound`, an `algorithm.InnerLoop` keeping its books as the simulated one does).
The round is journaled as adademo-expand's: every policy episode (success, length, initial joints, first frames)
and every demonstration. A stop (q, Ctrl-C) or a disconnect loses at most the episode in progress; the same command
resumes the round, and no failure gets two demonstrations. The ledger records the person's time.
"""

from __future__ import annotations

import queue
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from adademo_lerobot.configs import PolicyPathArgs, lerobot_choice
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.interventions import check_writable_features
from adademo_lerobot.dataset.layout import ADADEMO_DIR
from adademo_lerobot.dataset.metadata import has_dataset, read_episode_metadata, read_info
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.executors import ComputeArgs
from adademo_lerobot.expand import check_ledger_matches_dataset, next_round
from adademo_lerobot.files import exclusive_use
from adademo_lerobot.ledger import RoundJournal, append_ledger
from adademo_lerobot.records import Demonstration, TaskRoundRecord
from adademo_lerobot.strategies import StrategyConfig, default_strategy, planned_demos
from adademo_lerobot.strategies.base import Outcome
from adademo_lerobot.strategies.bookkeeping import JournaledRound, committed_demos, demo_entry
from adademo_lerobot.strategies.budgeted import BudgetedStrategy
from adademo_lerobot.strategies.estimates import failure_mean, prior_from_earlier_rounds
from adademo_lerobot.tables import table
from adademo_lerobot.takeover import DEMO_STARTS

JUDGES = ("auto", "keys", "teleop")
SOURCE = "human"
KEYS_HELP = "n/Right = next, r/Left = redo, s = success, f = failure, t = take over, q/Esc = stop"


@dataclass
class RecordDatasetArgs:
    repo_id: str = "local/robot"
    # The dataset the policy was trained on (recorded with this robot); new episodes are appended to it.
    root: str | None = None
    # The longest a policy episode or a demonstration may run, in seconds (the person usually ends it sooner).
    episode_time_s: float = 60.0


@dataclass
class RecordConfig(ComputeArgs):
    # The robot: --robot.type=NAME and its fields, any robot lerobot-record knows or an installed plugin
    # (e.g. --robot.type=so101_follower --robot.port=/dev/ttyACM0; `lerobot-record --help` lists them).
    robot: dict | None = lerobot_choice("robot")
    # The person's teleoperator: --teleop.type=NAME and its fields (e.g. so101_leader).
    teleop: dict | None = lerobot_choice("teleop")
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    dataset: RecordDatasetArgs = field(default_factory=RecordDatasetArgs)
    # Tasks of this round, comma-separated (task strings of the dataset); default: every task of the dataset.
    tasks: str | None = None
    # The strategy and its settings, adademo-expand's (same flags, same defaults): --strategy.type=adademo (until E
    # successes or CAP demos per task: --strategy.target_successes, --strategy.max_demos_per_task, or
    # --strategy.budget) or budgeted (--strategy.budget=B demos in the round); `docs/commands/record.md`.
    strategy: StrategyConfig = field(default_factory=default_strategy)
    # Demonstrations tried per failure before moving on (each redo counts).
    max_attempts: int = 3
    # Who marks success and ends episodes: `keys` (the person), `teleop` (the teleoperator's events, e.g.
    # adademo_scripted), `auto` (teleop if it reports events, else keys).
    judge: str = "auto"
    # `initial`: a failure is answered by a demonstration from the failed episode's start (the paper);
    # `takeover`: the person may take over while the policy goes wrong (t, or the teleoperator's intervention
    # event) and the correction is recorded from there. Hold the leader arm where the follower is before taking
    # over (the follower moves to the leader's pose at once).
    demo_start: str = "initial"
    seed: int = 0

    # Flags of earlier releases and where they went (`adademo_lerobot.cli` answers them in one line).
    MOVED_FLAGS: ClassVar[dict[str, str]] = {
        "target_successes": "strategy.target_successes",
        "max_demos_per_task": "strategy.max_demos_per_task",
        "max_eval_episodes_per_task": "strategy.max_eval_episodes_per_task",
    }

    def validate(self) -> None:
        """Checks of the flags alone (answered before LeRobot is imported: `adademo_lerobot.cli`)."""
        if self.robot is None:
            raise AdaDemoError("--robot.type is required (the robot to record with, e.g. so101_follower)")
        if self.teleop is None:
            raise AdaDemoError("--teleop.type is required (the person's teleoperator, e.g. so101_leader)")
        if self.policy.path is None:
            raise AdaDemoError("--policy.path is required (the policy whose failures the round answers)")
        self.validate_threads()
        self.strategy.validate()
        self.strategy.check_one_round("adademo-record")
        if not self.strategy.answers_failures_only():
            paying = " with --strategy.rollout_cost" if self.strategy.type == "budgeted" else ""
            raise AdaDemoError(
                f"--strategy.type={self.strategy.type}{paying} takes demonstrations from fresh initial states, "
                "which needs a simulated round (adademo-expand, adademo-run); adademo-record answers the policy's "
                f"failed episodes: use --strategy.type={' or '.join(StrategyConfig.answering_failures_only())}"
                + (" (without --strategy.rollout_cost)" if paying else "")
            )
        if self.dataset.root is None or not has_dataset(self.dataset.root):
            raise AdaDemoError(
                f"no LeRobot dataset at --dataset.root={self.dataset.root} (the dataset the policy was trained on, "
                "recorded with this robot, e.g. by lerobot-record)"
            )
        if self.max_attempts < 1:
            raise AdaDemoError(f"--max_attempts must be >= 1, got {self.max_attempts}")
        if self.dataset.episode_time_s <= 0:
            raise AdaDemoError(f"--dataset.episode_time_s must be > 0, got {self.dataset.episode_time_s}")
        if self.judge not in JUDGES:
            raise AdaDemoError(f"--judge must be one of {', '.join(JUDGES)}, got {self.judge!r}")
        if self.demo_start not in DEMO_STARTS:
            raise AdaDemoError(
                f"unknown --demo_start={self.demo_start!r}; choose one of {', '.join(DEMO_STARTS)}"
            )


class StopRecording(Exception):  # noqa: N818  (a request, not an error)
    """The person asked to stop (q / Esc)."""


class KeyboardPerson:
    """The person at the robot, answering on the keyboard through LeRobot's key listener."""

    def __init__(self):
        from lerobot.utils.keyboard_input import create_key_listener

        self.keys: queue.Queue[str] = queue.Queue()
        self.listener = create_key_listener(self.keys.put, controls_help=KEYS_HELP)
        if self.listener is None:
            raise AdaDemoError(
                "adademo-record needs the person's keys and gets none here (no display, and stdin is not a "
                "terminal): run it in an interactive terminal, or with a teleoperator that reports success "
                "(--judge=teleop)"
            )

        self._pressed: set[str] = set()  # keys read while an episode runs, not yet asked for

    def _wait(self, prompt: str, answers: dict[str, object]):
        print(f"{prompt}  [{KEYS_HELP}]", flush=True)
        self._pressed.clear()
        while True:
            key = self.keys.get().lower()
            if key in ("q", "esc"):
                raise StopRecording
            if key in answers:
                return answers[key]

    def ready(self, prompt: str) -> None:
        self._wait(prompt, {"n": True, "right": True, "enter": True})

    def _pressed_during_episode(self, *names: str) -> bool:
        while not self.keys.empty():
            key = self.keys.get_nowait().lower()
            if key in ("q", "esc"):
                raise StopRecording
            self._pressed.add("n" if key == "right" else key)
        found = bool(self._pressed & set(names))
        self._pressed -= set(names)
        return found

    def episode_over(self) -> bool:
        return self._pressed_during_episode("n")

    def takes_over(self) -> bool:
        return self._pressed_during_episode("t")

    def judge(self, task: str) -> bool:
        return self._wait(f"{task}: did the policy succeed? (s / f)", {"s": True, "f": False})

    def keep_demo(self, task: str) -> bool:
        return self._wait(f"{task}: keep this demonstration? (n keeps it, r records it again)", {
            "n": True, "right": True, "r": False, "left": False,
        })  # fmt: skip

    def close(self) -> None:
        self.listener.stop()


class TeleopPerson:
    """The teleoperator answers for the person through LeRobot's teleop events (success, end of episode)."""

    def __init__(self, teleop):
        self.teleop = teleop

    def _events(self) -> dict:
        from lerobot.teleoperators.utils import TeleopEvents

        events = self.teleop.get_teleop_events()
        return {e.value: bool(events.get(e, False)) for e in TeleopEvents}

    def ready(self, prompt: str) -> None:
        print(prompt, flush=True)

    def episode_over(self) -> bool:
        return self._events()["terminate_episode"]

    def takes_over(self) -> bool:
        return self._events()["is_intervention"]

    def judge(self, task: str) -> bool:
        return self._events()["success"]

    def keep_demo(self, task: str) -> bool:
        return self._events()["success"]

    def close(self) -> None:
        pass


def make_person(judge: str, teleop):
    if judge == "teleop" or (judge == "auto" and hasattr(teleop, "get_teleop_events")):
        if not hasattr(teleop, "get_teleop_events"):
            raise AdaDemoError(
                f"--judge=teleop: the {teleop.name} teleoperator reports no events; use --judge=keys"
            )
        return TeleopPerson(teleop)
    return KeyboardPerson()


def robot_features(robot, use_video: bool) -> dict[str, dict]:
    """The dataset features of what the robot reads and takes (as lerobot-record builds them)."""
    from lerobot.utils.constants import ACTION, OBS_STR
    from lerobot.utils.feature_utils import hw_to_dataset_features

    return {
        **hw_to_dataset_features(robot.action_features, ACTION),
        **hw_to_dataset_features(robot.observation_features, OBS_STR, use_video),
    }


def check_recorded_with(root: Path, robot, features: dict[str, dict]) -> None:
    """The dataset was recorded with this robot: same robot type, same features (names and shapes)."""
    info = read_info(root)
    if info.get("robot_type") != robot.robot_type:
        raise AdaDemoError(
            f"{root} was recorded with robot {info.get('robot_type')!r}, not {robot.robot_type!r}: record its "
            "rounds with the robot it was recorded with"
        )
    found = info.get("features", {})
    problems = []
    for key, ft in features.items():
        if key not in found:
            problems.append(f"{key} is not in the dataset")
        elif tuple(found[key]["shape"]) != tuple(ft["shape"]) or found[key].get("names") != ft.get("names"):
            problems.append(
                f"{key} differs (dataset {tuple(found[key]['shape'])}, robot {tuple(ft['shape'])})"
            )
    problems += [
        f"{k} is not read by the robot" for k in found if k.startswith("observation.") and k not in features
    ]
    if problems:
        raise AdaDemoError(
            f"{root} was recorded with another {robot.robot_type} setup: " + "; ".join(problems)
        )


def predicted_demos(rate: float | None, target: int, cap: int) -> int:
    """The paper's N_k = E / SR_k - E, capped (CAP when the task has never succeeded or was never evaluated)."""
    return cap if rate is None else planned_demos(target, rate, cap)


def plan_lines(root: Path, round_index: int, tasks: list[str], strategy, episode_time_s: float) -> list[str]:
    """Principle A before the person starts: predicted demos and time per task from the latest success rates
    (adademo: N = E/SR - E, capped; budgeted: the budget's first split), for the strategy as it `start`ed."""
    eps = read_episode_metadata(root)
    fps = read_info(root)["fps"]
    budgeted = isinstance(strategy, BudgetedStrategy)
    split = strategy.first_split(root, round_index, tasks)[1] if budgeted else {}
    rows, total_s = [], 0.0
    for task in tasks:
        alpha, beta = prior_from_earlier_rounds(root, round_index, task, strategy.posterior_decay)
        seen = alpha + beta > 2
        rate = 1 - failure_mean((alpha, beta)) if seen else None
        lengths = eps.loc[eps.task == task, "length"]
        episode_s = float(lengths.mean()) / fps if len(lengths) else episode_time_s
        if budgeted:  # N demos at failures: about N / P(failure) policy episodes and N demonstrations
            n = split[task]
            episodes = n / failure_mean((alpha, beta)) + n
        else:  # E successes and about N failures, each answered by one demonstration
            n = predicted_demos(rate, strategy.target_successes, strategy.cap)
            episodes = strategy.target_successes + 2 * n
        seconds = episodes * episode_s
        total_s += seconds
        sr = f"{100 * rate:.0f}%" if seen else "unknown (no round yet)"
        rows.append([task, sr, n, f"{episode_s:.1f}", f"{seconds / 60:.1f}"])
    if budgeted:
        head = (
            f"round {round_index} plan (budgeted, B={strategy.budget}, CAP={strategy.cap}): the budget's first "
            "split by each task's expected failure rate (re-split after every episode), and the time at the "
            "recorded episode length"
        )
    else:
        head = (
            f"round {round_index} plan (E={strategy.target_successes}, CAP={strategy.cap}): demos each task will "
            "likely need, N = E/SR - E, and the time at the recorded episode length"
        )
    return [
        head,
        table(["task", "latest success", "predicted demos", "episode s", "minutes"], rows),
        f"about {total_s / 60:.0f} minutes of episodes, plus resetting scenes",
    ]


class Session:
    """The connected robot, teleoperator, policy and person of one round, and its journal."""

    def __init__(self, cfg: RecordConfig, robot, teleop, person, features: dict, round_index: int):
        import torch
        from lerobot.common.control_utils import predict_action
        from lerobot.policies.utils import make_robot_action
        from lerobot.utils.constants import ACTION, OBS_STR
        from lerobot.utils.feature_utils import build_dataset_frame

        from adademo_lerobot.policy import load_policy

        self.cfg, self.robot, self.teleop, self.person = cfg, robot, teleop, person
        self.features, self.round_index = features, round_index
        self.root = Path(cfg.dataset.root)
        self.dataset = DemoDataset.open_recorded(cfg.dataset.repo_id, self.root)
        self.journal = RoundJournal(self.root, round_index)
        torch.set_num_threads(cfg.torch_threads)
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

    def demonstration(self, task: str, failed: dict) -> tuple[Demonstration | None, int, float]:
        """The person's demonstration from the failed episode's start: (demo or None after every attempt gave
        none, attempts, seconds)."""
        start = time.perf_counter()
        for attempt in range(1, self.cfg.max_attempts + 1):
            if self.simulated:
                self.robot.reset_scene(failed["seed"])
            else:
                frames = ", ".join(str(self.root / p) for p in failed["first_frames"].values())
                joints = ", ".join(
                    f"{n}={v:.3g}" for n, v in zip(self.state_names, failed["initial_state"], strict=True)
                )
                self.person.ready(
                    f"{task}: put the scene back as it was when episode {failed['seed']} started "
                    f"({'first frame: ' + frames + '; ' if frames else ''}joints: {joints}), press n, then "
                    "teleoperate the task; press n when done"
                )
            frames_out, first = self._teleoperate()
            if self.person.keep_demo(task):
                demo = Demonstration(
                    task, np.asarray(self._joints(first)), failed["seed"], frames_out, attempt
                )
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
    failed episode's start, or that correction. Its books are the simulated round's (`JournaledRound`): everything
    is journaled first, so after a stop the strategy runs again over the same states and reuses what was done."""

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
        failed = self.journal.evaluations(task)[seed]
        if (task, seed) in self._corrections:
            (demo, seconds), attempts = self._corrections.pop((task, seed)), 1
        else:  # from the episode's start (a correction a stop interrupted too: the robot has moved since)
            self._use(task)
            demo, attempts, seconds = self.session.demonstration(task, failed)
        if demo is None:
            entry = {
                "type": "expert_failure",
                "task": task,
                "seed": int(seed),
                "attempts": attempts,
                "initial_state": failed["initial_state"],
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
            "robot": self.session.robot.robot_type,
            "teleop": self.session.cfg.teleop.type,
            "person_seconds": {"policy_episodes": round(policy_s, 1), "demonstrations": round(demo_s, 1)},
        }
        return record


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")[:60] or "task"


def dataset_tasks(root: Path) -> list[str]:
    import pandas as pd

    return list(pd.read_parquet(root / "meta" / "tasks.parquet").index)


def run_record(cfg: RecordConfig) -> list[TaskRoundRecord]:
    cfg.validate()
    root = Path(cfg.dataset.root)
    check_dataset_integrity(root)
    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    from adademo_lerobot.policy import check_policy

    robot = make_robot_from_config(cfg.robot)
    teleop = make_teleoperator_from_config(cfg.teleop)
    info = read_info(root)
    use_video = any(ft.get("dtype") == "video" for ft in info.get("features", {}).values())
    features = robot_features(robot, use_video)
    check_recorded_with(root, robot, features)
    check_writable_features(root, features, "adademo-record")  # e.g. LeRobot's DAgger `intervention`: carried
    check_policy(cfg.policy.path, features)
    known = dataset_tasks(root)
    tasks = [t.strip() for t in cfg.tasks.split(",")] if cfg.tasks else known
    unknown = [t for t in tasks if t not in known]
    if unknown:
        raise AdaDemoError(f"--tasks: {unknown} not in the dataset (its tasks: {known})")
    with exclusive_use(root, "adademo-record"):  # one command at a time on a dataset
        round_index = next_round(root)
        strategy = cfg.strategy.build(1)
        person = make_person(cfg.judge, teleop)
        session = None
        try:
            robot.connect()
            teleop.connect()
            session = Session(cfg, robot, teleop, person, features, round_index)
            ctx = PersonRound(session, tasks)
            started = session.journal.of_type("start")
            decided = strategy.start(ctx, started[0] if started else None)
            print(
                "\n".join(plan_lines(root, round_index, tasks, strategy, cfg.dataset.episode_time_s)),
                flush=True,
            )
            session.journal.start(
                {
                    "strategy": strategy.name,
                    **decided,
                    "source": SOURCE,
                    "policy_path": str(cfg.policy.path),
                    "robot": robot.robot_type,
                    "teleop": cfg.teleop.type,
                    "seed": cfg.seed,
                    **({"demo_start": cfg.demo_start} if cfg.demo_start != "initial" else {}),
                }
            )
            records = [ctx.with_costs(r) for r in strategy.expand(ctx)]
        except StopRecording:
            raise KeyboardInterrupt from None
        except ConnectionError as err:  # LeRobot's DeviceNotConnectedError, a serial port gone, ...
            raise AdaDemoError(
                f"the robot or teleoperator disconnected ({' '.join(str(err).split())[:200]}): reconnect it and rerun "
                "the same command; the round resumes where it stopped"
            ) from None
        finally:
            person.close()
            for device in (teleop, robot):
                if device.is_connected:
                    device.disconnect()
        check_ledger_matches_dataset(root, round_index, records)
        append_ledger(root, records)
        session.journal.finish()
        print(
            table(
                ["task", "policy episodes", "successes", "demos", "gave up", "person minutes"],
                [
                    [
                        r.task,
                        r.eval_episodes,
                        r.successes,
                        r.demos_added,
                        r.expert_failures,
                        f"{r.wall_seconds / 60:.1f}",
                    ]
                    for r in records
                ],
            )
        )
        print(f"round {round_index}: {sum(r.demos_added for r in records)} demonstrations added to {root}")
    return records
