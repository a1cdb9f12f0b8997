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
furthest below its share of the budget going next. With `--strategy.rollout_cost=c` as well, B pays for the policy
episodes too (c each) and, where a failure would cost too many episodes to find, for demonstrations from a new scene
the person sets up (no policy episode before it). Strategies that sample their own initial states (uniform,
task_only, `--strategy.rank_states=knn`) need a simulated round and are refused.
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

from pathlib import Path

from adademo_lerobot.core.episodes import TaskRoundRecord
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.interrupts import stop_command
from adademo_lerobot.core.tables import table
from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.info import read_info
from adademo_lerobot.dataset.interventions import check_writable_features
from adademo_lerobot.dataset.ledger import append_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.store import recover_unless_in_use
from adademo_lerobot.loop.configs import RecordConfig
from adademo_lerobot.loop.expand import check_ledger_matches_dataset, next_round
from adademo_lerobot.loop.person import StopRecording, make_person
from adademo_lerobot.loop.robot_round import SOURCE, PersonRound, Session
from adademo_lerobot.strategies import planned_demos
from adademo_lerobot.strategies.budgeted import BudgetedStrategy
from adademo_lerobot.strategies.estimates import failure_mean, prior_from_earlier_rounds


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
            f"{root} was recorded with another {robot.robot_type} setup: "
            + "; ".join(problems)
            + " (set the robot as it was recorded: its cameras and their size, e.g. --robot.cameras=... or, on "
            "adademo_sim, --robot.image_size / --robot.camera / --robot.scene_state)"
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
    paying = budgeted and strategy.rollout_cost is not None
    split = strategy.first_split(root, round_index, tasks)[1] if budgeted else {}
    rows, total_s = [], 0.0
    for task in tasks:
        alpha, beta = prior_from_earlier_rounds(root, round_index, task, strategy.posterior_decay)
        seen = alpha + beta > 2
        rate = 1 - failure_mean((alpha, beta)) if seen else None
        lengths = eps.loc[eps.task == task, "length"]
        episode_s = float(lengths.mean()) / fps if len(lengths) else episode_time_s
        if budgeted:
            # Paying: its share of the budget is in episodes (policy episodes at their cost, demonstrations at 1);
            # else N demos at failures, about N / P(failure) policy episodes and N demonstrations.
            n = split[task]
            episodes = n if paying else n / failure_mean((alpha, beta)) + n
        else:  # E successes and about N failures, each answered by one demonstration
            n = predicted_demos(rate, strategy.target_successes, strategy.cap)
            episodes = strategy.target_successes + 2 * n
        seconds = episodes * episode_s
        total_s += seconds
        sr = f"{100 * rate:.0f}%" if seen else "unknown (no round yet)"
        rows.append([task, sr, n, f"{episode_s:.1f}", f"{seconds / 60:.1f}"])
    if paying:
        head = (
            f"round {round_index} plan (budgeted paying for policy episodes at {strategy.rollout_cost:g}, "
            f"B={strategy.budget}, CAP={strategy.cap}): the budget's first split by each task's expected failure "
            "rate, in episodes (policy episodes and demonstrations; re-split after every episode), and the time at "
            "the recorded episode length"
        )
    elif budgeted:
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
        table(
            ["task", "latest success", "episodes" if paying else "predicted demos", "episode s", "minutes"],
            rows,
        ),
        f"about {_duration(total_s)} of episodes, plus resetting scenes",
    ]


def _duration(seconds: float) -> str:
    """A plan's time as a person reads it: seconds under two minutes, then minutes."""
    return f"{seconds:.0f} seconds" if seconds < 120 else f"{seconds / 60:.0f} minutes"


def dataset_tasks(root: Path) -> list[str]:
    import pandas as pd

    return list(pd.read_parquet(root / "meta" / "tasks.parquet").index)


def run_record(cfg: RecordConfig) -> list[TaskRoundRecord]:
    cfg.validate()
    root = Path(cfg.dataset.root)
    # A write a kill left half-done is rolled back before the dataset is judged damaged.
    recover_unless_in_use(root, "adademo-record")
    check_dataset_integrity(root)
    from lerobot.robots.utils import make_robot_from_config
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    from adademo_lerobot.evaluation.policy import check_policy

    robot = make_robot_from_config(cfg.robot)
    teleop = make_teleoperator_from_config(cfg.teleop)
    info = read_info(root)
    use_video = any(ft.get("dtype") == "video" for ft in info.get("features", {}).values())
    features = robot_features(robot, use_video)
    check_recorded_with(root, robot, features)
    check_writable_features(root, features, "adademo-record")  # e.g. LeRobot's DAgger `intervention`: carried
    check_policy(cfg.policy.path, features, "the robot's observations and actions")
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
        except StopRecording:  # the person's request: the command stops as on Ctrl-C
            stop_command()
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
        corrections = sum(r.corrections for r in records)
        demos = sum(r.demos_added for r in records) - corrections
        added = f"{demos} demonstration{'s' * (demos != 1)}" + (
            f" and {corrections} correction{'s' * (corrections != 1)}" if corrections else ""
        )
        print(f"round {round_index}: {added} added to {root}")
    return records
