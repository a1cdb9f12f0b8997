"""`adademo-record`: one AdaDemo round on a robot, with a person in Algorithm 1's inner loop.

    adademo-record --robot.type=so101_follower --robot.port=/dev/ttyACM0 --robot.cameras=... \\
        --teleop.type=so101_leader --teleop.port=/dev/ttyACM1 --policy.path=CKPT \\
        --dataset.repo_id=USER/NAME --dataset.root=FOLDER --target_successes=5 --max_demos_per_task=10

For every task of the dataset (or `--tasks`), until E successes or CAP demonstrations:
  1. the person sets up a new scene and the policy runs an episode (the person ends it early with n);
  2. the person marks it a success (s) or a failure (f);
  3. after a failure the person puts the scene back as it was when that episode started (its first camera frame is
     saved to look at, its initial joint positions are printed) and teleoperates a demonstration from there, which
     is appended to the dataset with its provenance (n keeps it, r records it again).
With `--demo_start=takeover` the person may instead take over while the policy goes wrong (t, or the
teleoperator's intervention event): the policy episode counts as a failure and the person's correction is recorded
from that moment, with the robot's joint positions then as its start state (no scene to set up again). A failure
the person did not take over is answered as above.
Before the first episode, a plan from each task's latest success rate (the paper's N_k = E/SR_k - E) says how many
demonstrations each task will likely need and how long that takes at the dataset's episode length (principle A).

Keys (LeRobot's key listener, as in lerobot-record): n or Right = next, r or Left = redo, s = success,
f = failure, t = take over (with --demo_start=takeover), q or Esc = stop. A simulated robot (`adademo_sim`) sets its scenes itself, and a teleoperator that
reports LeRobot's teleop events (`adademo_scripted`) answers for the person.

The loop is Algorithm 1's own (`algorithm.collect_on_failed_states`, as adademo-expand runs it) with a person-backed
round context (`PersonRound`). The round is journaled as adademo-expand's: every policy episode (success, length, initial joints, first frames)
and every demonstration. A stop (q, Ctrl-C) or a disconnect loses at most the episode in progress; the same command
resumes the round, and no failure gets two demonstrations. The ledger records the person's time.
"""

from __future__ import annotations

import queue
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from adademo_lerobot.algorithm import collect_on_failed_states
from adademo_lerobot.configs import PolicyPathArgs, lerobot_choice
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.layout import ADADEMO_DIR, CORRECTION_SOURCE
from adademo_lerobot.dataset.metadata import has_dataset, read_episode_metadata, read_info
from adademo_lerobot.dataset.store import DemoDataset
from adademo_lerobot.errors import AdaDemoError
from adademo_lerobot.expand import next_round
from adademo_lerobot.files import exclusive_use
from adademo_lerobot.ledger import RoundJournal, append_ledger
from adademo_lerobot.records import Demonstration, TaskRoundRecord
from adademo_lerobot.strategies import planned_demos
from adademo_lerobot.strategies.base import Outcome, default_eval_bound
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
class RecordConfig:
    # The robot: --robot.type=NAME and its fields, any robot lerobot-record knows or an installed plugin
    # (e.g. --robot.type=so101_follower --robot.port=/dev/ttyACM0; `lerobot-record --help` lists them).
    robot: dict | None = lerobot_choice("robot")
    # The person's teleoperator: --teleop.type=NAME and its fields (e.g. so101_leader).
    teleop: dict | None = lerobot_choice("teleop")
    policy: PolicyPathArgs = field(default_factory=PolicyPathArgs)
    dataset: RecordDatasetArgs = field(default_factory=RecordDatasetArgs)
    # Tasks of this round, comma-separated (task strings of the dataset); default: every task of the dataset.
    tasks: str | None = None
    # E: policy successes that end a task's round.
    target_successes: int = 5
    # CAP: at most this many demonstrations per task in the round.
    max_demos_per_task: int = 10
    # Bound on policy episodes per task (default 2 x (E + CAP)).
    max_eval_episodes_per_task: int | None = None
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
    device: str = "cpu"

    def validate(self) -> None:
        """Checks of the flags alone (answered before LeRobot is imported: `adademo_lerobot.cli`)."""
        if self.robot is None:
            raise AdaDemoError("--robot.type is required (the robot to record with, e.g. so101_follower)")
        if self.teleop is None:
            raise AdaDemoError("--teleop.type is required (the person's teleoperator, e.g. so101_leader)")
        if self.policy.path is None:
            raise AdaDemoError("--policy.path is required (the policy whose failures the round answers)")
        if self.dataset.root is None or not has_dataset(self.dataset.root):
            raise AdaDemoError(
                f"no LeRobot dataset at --dataset.root={self.dataset.root} (the dataset the policy was trained on, "
                "recorded with this robot, e.g. by lerobot-record)"
            )
        for flag in ("target_successes", "max_demos_per_task", "max_attempts"):
            if getattr(self, flag) < 1:
                raise AdaDemoError(f"--{flag} must be >= 1, got {getattr(self, flag)}")
        if self.max_eval_episodes_per_task is not None and self.max_eval_episodes_per_task < 1:
            raise AdaDemoError(
                f"--max_eval_episodes_per_task must be >= 1, got {self.max_eval_episodes_per_task}"
            )
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


def plan_lines(root: Path, round_index: int, tasks: list[str], cfg: RecordConfig) -> list[str]:
    """Principle A before the person starts: predicted demos and time per task from the latest success rates."""
    eps = read_episode_metadata(root)
    fps = read_info(root)["fps"]
    rows, total_s = [], 0.0
    for task in tasks:
        alpha, beta = prior_from_earlier_rounds(root, round_index, task)
        seen = alpha + beta > 2
        rate = 1 - failure_mean((alpha, beta)) if seen else None
        n = predicted_demos(rate, cfg.target_successes, cfg.max_demos_per_task)
        lengths = eps.loc[eps.task == task, "length"]
        episode_s = float(lengths.mean()) / fps if len(lengths) else cfg.dataset.episode_time_s
        # E successes and about N failures (each answered by one demonstration) at the recorded episode length.
        seconds = (cfg.target_successes + 2 * n) * episode_s
        total_s += seconds
        sr = f"{100 * rate:.0f}%" if seen else "unknown (no round yet)"
        rows.append([task, sr, n, f"{episode_s:.1f}", f"{seconds / 60:.1f}"])
    return [
        f"round {round_index} plan (E={cfg.target_successes}, CAP={cfg.max_demos_per_task}): demos each task will "
        "likely need, N = E/SR - E, and the time at the recorded episode length",
        table(["task", "latest success", "predicted demos", "episode s", "minutes"], rows),
        f"about {total_s / 60:.0f} minutes of episodes, plus resetting scenes",
    ]


class Session:
    """The connected robot, teleoperator, policy and person of one round, and its journal."""

    def __init__(self, cfg: RecordConfig, robot, teleop, person, features: dict, round_index: int):
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

    # -- one task ---------------------------------------------------------------------------------------------
    def run_task(self, task: str) -> TaskRoundRecord:
        """Algorithm 1's inner loop for one task, the person in it."""
        cfg = self.cfg
        target, cap = cfg.target_successes, cfg.max_demos_per_task
        max_evals = cfg.max_eval_episodes_per_task or default_eval_bound(target, cap)
        self._recover_demos(task)
        if hasattr(self.robot, "select_task"):
            self.robot.select_task(task)
        else:
            self.person.ready(f"next task: {task!r}: set up its scene, then press n")
        ctx = PersonRound(self)
        record = ctx.new_record(task, "adademo", target, cap)
        collect_on_failed_states(ctx, task, record, target, cap, max_evals)
        return self._with_costs(record)

    def store_answer(
        self, task: str, failed: dict, demo: Demonstration | None, attempts: int, seconds: float
    ) -> None:
        """A failure's answer, appended and journaled: the demonstration (or correction), or that none came."""
        if demo is None:
            self.journal.append(
                {"type": "expert_failure", "task": task, "seed": failed["seed"], "attempts": attempts}
            )
            return
        self.dataset.append_recorded(
            self.robot.robot_type, [demo], self.round_index, SOURCE, self.cfg.teleop.type
        )
        entry = {"type": "demo", "task": task, "seed": demo.seed, "steps": len(demo.frames)}
        if demo.is_correction:
            entry["start_step"] = demo.start_step
        self.journal.append({**entry, "seconds": round(seconds, 3)})

    def _recover_demos(self, task: str) -> None:
        """A stop between a demonstration's append and its journal entry: the dataset has it, so journal it."""
        eps = read_episode_metadata(self.root)
        mine = eps[
            (eps.task == task)
            & (eps["adademo/round"] == self.round_index)
            & eps["adademo/source"].isin([SOURCE, CORRECTION_SOURCE])
        ]
        for seed, length, source, step in zip(
            mine["adademo/seed"],
            mine["length"],
            mine["adademo/source"],
            mine["adademo/start_step"],
            strict=True,
        ):
            if int(seed) not in self.journal.demos(task):
                entry = {
                    "type": "demo",
                    "task": task,
                    "seed": int(seed),
                    "steps": int(length),
                    "seconds": 0.0,
                }
                if source == CORRECTION_SOURCE:
                    entry["start_step"] = int(step)
                self.journal.append(entry)

    def _with_costs(self, record: TaskRoundRecord) -> TaskRoundRecord:
        """The ledger's figures the loop does not count: every policy episode run and the person's time."""
        evals = list(self.journal.evaluations(record.task).values())
        demos = list(self.journal.demos(record.task).values())
        policy_s = sum(e.get("seconds", 0.0) for e in evals)
        demo_s = sum(d.get("seconds", 0.0) for d in demos)
        record.policy_path = str(self.cfg.policy.path)
        record.eval_episodes_run = len(evals)
        record.eval_env_steps = sum(e["steps"] for e in evals)
        record.wall_seconds = round(policy_s + demo_s, 1)
        record.extra = {
            "robot": self.robot.robot_type,
            "teleop": self.cfg.teleop.type,
            "person_seconds": {"policy_episodes": round(policy_s, 1), "demonstrations": round(demo_s, 1)},
        }
        return record


class PersonRound:
    """The round context Algorithm 1's inner loop (`collect_on_failed_states`) talks to, with a person and a robot
    behind it. Evaluating a state is a policy episode the person judges, or takes over (its correction is
    recorded at once, while the robot is where the person took over); a demonstration is the person's, from the
    failed episode's start, or that correction. Everything is journaled first: after a stop, the loop runs again
    over the same states and reuses what was done."""

    batch_size = 1  # one robot, one episode at a time

    def __init__(self, session: Session):
        self.session, self.journal = session, session.journal
        self.seed, self.round_index = session.cfg.seed, session.round_index
        self._corrections: dict[int, tuple[Demonstration | None, float]] = {}

    def new_record(self, task: str, strategy: str, target_successes: int, cap: int) -> TaskRoundRecord:
        return TaskRoundRecord(self.round_index, task, strategy, target_successes, cap, None, None)

    def evaluate(self, task: str, seeds: list[int]) -> list[Outcome]:
        outcomes = []
        for seed in seeds:
            entry = self.journal.evaluations(task).get(seed)
            if entry is None:
                entry = self.session.policy_episode(task, seed)
                self.journal.append(entry)  # first: a stop during the correction leaves a failure to answer
                if "takeover_step" in entry:
                    self._corrections[seed] = self.session.correction(task, entry)
            outcomes.append(Outcome(seed, bool(entry["success"])))
        return outcomes

    def ask_expert(self, task: str, seeds: list[int]) -> None:
        """A person does one demonstration at a time, when asked (`collect_demo`)."""

    def collect_demo(self, task: str, seed: int, record: TaskRoundRecord) -> bool:
        demos, gave_up = self.journal.demos(task), self.journal.expert_failures(task)
        if seed not in demos and seed not in gave_up:  # not answered yet (also after a stop)
            failed = self.journal.evaluations(task)[seed]
            if seed in self._corrections:
                demo, seconds = self._corrections.pop(seed)
                self.session.store_answer(task, failed, demo, 1, seconds)
            else:  # from the episode's start (a correction a stop interrupted too: the robot has moved since)
                self.session.store_answer(task, failed, *self.session.demonstration(task, failed))
        if seed in demos:
            entry = demos[seed]
            record.demos_added += 1
            record.collection_env_steps += entry["steps"]
            record.demo_frames += entry["steps"]
            record.corrections += "start_step" in entry
            return True
        record.expert_failures += 1
        return False

    def progress(self, task: str, record: TaskRoundRecord) -> None:
        pass


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
    check_policy(cfg.policy.path, features)
    known = dataset_tasks(root)
    tasks = [t.strip() for t in cfg.tasks.split(",")] if cfg.tasks else known
    unknown = [t for t in tasks if t not in known]
    if unknown:
        raise AdaDemoError(f"--tasks: {unknown} not in the dataset (its tasks: {known})")
    with exclusive_use(root, "adademo-record"):  # one command at a time on a dataset
        round_index = next_round(root)
        print("\n".join(plan_lines(root, round_index, tasks, cfg)), flush=True)
        person = make_person(cfg.judge, teleop)
        session = None
        try:
            robot.connect()
            teleop.connect()
            session = Session(cfg, robot, teleop, person, features, round_index)
            session.journal.start(
                {
                    "strategy": "adademo",
                    "source": SOURCE,
                    "target_successes": cfg.target_successes,
                    "max_demos_per_task": cfg.max_demos_per_task,
                    "policy_path": str(cfg.policy.path),
                    "robot": robot.robot_type,
                    "teleop": cfg.teleop.type,
                    "seed": cfg.seed,
                    **({"demo_start": cfg.demo_start} if cfg.demo_start != "initial" else {}),
                }
            )
            records = [session.run_task(task) for task in tasks]
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
