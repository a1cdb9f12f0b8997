"""adademo-record: an AdaDemo round with a person in the loop, through LeRobot's Robot and Teleoperator interfaces.

Without hardware: the `adademo_sim` robot (a MetaWorld scene with a camera) and the `adademo_scripted` teleoperator
(the scripted expert, answering the person's keys through LeRobot's teleop events) are real implementations of
those interfaces, installed as LeRobot plugins, so the user's stock workflow runs first: `lerobot-record` records
the initial demonstrations and `lerobot-train` trains the policy; then adademo-record runs a round, is stopped
halfway, and the same command finishes it.
"""

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    BIN,
    assert_cli_error,
    file_digests,
    requires_rendering,
    run_cli,
    stock_tiny_train,
)

from adademo_lerobot.dataset.check import check_dataset_integrity
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.loop.record import predicted_demos

SIM = ["--robot.type=adademo_sim", "--robot.tasks=reach-v3,push-v3", "--robot.image_size=32"]
# The strategy flags are adademo-expand's (--strategy.type=adademo by default).
SMALL_ROUND = ["--strategy.target_successes=2", "--strategy.max_demos_per_task=2"]


def test_predicted_demos_is_the_papers_estimate_capped():
    assert predicted_demos(0.5, target=5, cap=10) == 5  # E / SR - E
    assert predicted_demos(0.25, target=5, cap=10) == 10  # 15, capped
    assert predicted_demos(1.0, target=5, cap=10) == 0
    assert predicted_demos(0.0, target=5, cap=10) == 10  # never succeeded: up to CAP
    assert predicted_demos(None, target=5, cap=10) == 10  # never evaluated


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, Path]:
    """Two tasks recorded by stock `lerobot-record` on the simulated robot, and an ACT trained by `lerobot-train`."""
    tmp = tmp_path_factory.mktemp("robot")
    root = tmp / "dataset"
    for task, resume in (("reach-v3", "false"), ("push-v3", "true")):
        run_cli(
            "lerobot-record",
            *SIM,
            f"--robot.task={task}",
            "--teleop.type=adademo_scripted",
            "--dataset.repo_id=local/robot",
            f"--dataset.root={root}",
            f"--dataset.single_task={task}",
            "--dataset.fps=80",
            "--dataset.num_episodes=2",
            "--dataset.episode_time_s=1",
            "--dataset.reset_time_s=0",
            "--dataset.push_to_hub=false",
            f"--resume={resume}",
            "--display_data=false",
            "--play_sounds=false",
        )
    return root, stock_tiny_train(root, tmp / "train")


def record_args(root: Path, checkpoint: Path, *extra: str, strategy: list[str] = SMALL_ROUND) -> list[str]:
    return [
        *SIM,
        "--teleop.type=adademo_scripted",
        f"--policy.path={checkpoint}",
        "--dataset.repo_id=local/robot",
        f"--dataset.root={root}",
        "--dataset.episode_time_s=1",
        *strategy,
        *extra,
    ]


@requires_rendering
def test_stock_lerobot_record_uses_the_simulated_robot(recorded):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root, _ = recorded
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["robot_type"] == "adademo_sim" and info["total_episodes"] == 4
    assert info["features"]["observation.state"]["names"] == ["x.pos", "y.pos", "z.pos", "gripper.pos"]
    assert info["features"]["action"]["names"] == ["x.vel", "y.vel", "z.vel", "gripper.vel"]
    frame = LeRobotDataset("local/robot", root=root, video_backend="pyav")[0]
    assert frame["observation.images.corner2"].shape == (3, 32, 32)
    assert frame["observation.images.corner2"].std() > 0.01  # the scene, not a blank frame


@requires_rendering
def test_a_round_with_a_person_in_the_loop_stopped_then_resumed(recorded, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    source, checkpoint = recorded
    root = tmp_path / "dataset"
    subprocess.run(["cp", "-r", str(source), str(root)], check=True)
    args = record_args(root, checkpoint)

    # Stopped (Ctrl-C) once the first demonstration is journaled.
    proc = subprocess.Popen(
        [str(BIN / "adademo-record"), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        # Ctrl-C as in a terminal, even when the suite itself runs in the background (which ignores SIGINT).
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    journal, deadline = root / "meta" / "adademo" / "journal-round-001.jsonl", time.time() + 600
    while not (journal.exists() and '"type": "demo"' in journal.read_text()):
        assert time.time() < deadline and proc.poll() is None, proc.communicate()[1][-3000:]
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    assert "rerun the same command to resume" in err.decode()
    check_dataset_integrity(root)  # whole: at most the episode in progress was lost

    done = run_cli("adademo-record", *args)
    assert "round 1 plan" in done.stdout and "predicted demos" in done.stdout

    ledger = [r for r in read_ledger(root) if r["round"] == 1]
    assert [r["task"] for r in ledger] == ["reach-v3", "push-v3"]
    evaluations = [e for e in read_round_evaluations(root, 1) if e["type"] == "eval"]
    failures = {(e["task"], e["seed"]) for e in evaluations if not e["success"]}
    eps = read_episode_metadata(root)
    new = eps[eps["adademo/round"] == 1]
    for r in ledger:  # the stopping rule: E successes or CAP demos (or the evaluation bound)
        mine = new[new.task == r["task"]]
        assert r["demos_added"] == len(mine) <= 2
        assert r["successes"] >= 2 or r["demos_added"] == 2 or r["eval_bound_hit"]
        assert r["collector"] == {"type": "person", "teleop": "adademo_scripted", "robot": "adademo_sim"}
        assert r["wall_seconds"] > 0
    # Every demonstration answers one failed policy episode of its task, and no failure got two.
    answered = list(zip(new.task, new["adademo/seed"], strict=True))
    assert len(answered) == len(set(answered)) and set(answered) <= failures
    assert set(new["adademo/source"]) == {"human"} and set(new["adademo/collector"]) == {"adademo_scripted"}
    assert all(len(s) == 4 for s in new["adademo/initial_state"])  # the robot's initial joint positions
    for e in evaluations:  # each policy episode's first camera frame is kept, referenced from its record
        assert (root / e["first_frames"]["corner2"]).is_file()
        assert len(e["initial_state"]) == 4
    stock = LeRobotDataset("local/robot", root=root, video_backend="pyav")
    assert stock.meta.total_episodes == 4 + len(new)
    assert np.isfinite(stock[len(stock) - 1]["action"].numpy()).all()
    assert not journal.exists()  # the round is finished: its journal is archived with the evaluations


@requires_rendering
@pytest.mark.slow
def test_a_budgeted_round_with_a_person_spends_exactly_its_budget_every_round(recorded, tmp_path):
    """`--strategy.type=budgeted --strategy.budget=3`, the simulated run's strategy with a person in it: each of two
    rounds adds exactly 3 demonstrations at failed policy episodes (the second round counts from its own start, not
    from the first round's), and the second round's split starts from the first round's outcomes."""
    source, checkpoint = recorded
    root = tmp_path / "dataset"
    subprocess.run(["cp", "-r", str(source), str(root)], check=True)
    args = record_args(root, checkpoint, strategy=["--strategy.type=budgeted", "--strategy.budget=3"])
    for round_index in (1, 2):
        done = run_cli("adademo-record", *args)
        assert f"round {round_index} plan (budgeted, B=3, CAP=50)" in done.stdout, done.stdout
        ledger = [r for r in read_ledger(root) if r["round"] == round_index]
        assert [r["task"] for r in ledger] == ["reach-v3", "push-v3"]
        assert {r["strategy"] for r in ledger} == {"budgeted"}
        eps = read_episode_metadata(root)
        new = eps[eps["adademo/round"] == round_index]
        assert sum(r["demos_added"] for r in ledger) == len(new) == 3
        assert {r["extra"]["round_spent"] for r in ledger} == {3}
        failures = {
            (e["task"], e["seed"])
            for e in read_round_evaluations(root, round_index)
            if e["type"] == "eval" and not e["success"]
        }
        answered = list(zip(new.task, new["adademo/seed"], strict=True))
        assert len(answered) == len(set(answered)) and set(answered) <= failures
        priors = [r["extra"]["prior"] for r in ledger]
        if round_index == 1:
            assert priors == [[1.0, 1.0], [1.0, 1.0]]  # nothing seen before the first round
        else:  # the first round's outcomes, halved: not the prior of a first round
            assert priors != [[1.0, 1.0], [1.0, 1.0]]
    check_dataset_integrity(root)


@requires_rendering
@pytest.mark.slow  # the strategy itself: test_expand.py's rollout-cost rounds, by default
def test_a_person_runs_the_strategy_that_pays_for_its_policy_episodes(recorded, tmp_path):
    """`--strategy.rollout_cost` at a robot, two rounds within their budgets of episodes: in the first, a policy
    episode costs 3 demonstrations, so none is worth running and every demonstration is the person's from a new
    scene; in the second (cost 0.5, the episodes split by expected failure, unsure tasks probed) policy episodes
    are run, each failure answered at its own start, the rest from new scenes."""
    source, checkpoint = recorded
    root = tmp_path / "dataset"
    subprocess.run(["cp", "-r", str(source), str(root)], check=True)
    paying = ["--strategy.type=budgeted", "--strategy.budget=4"]
    second = ["--strategy.rollout_cost=0.5", "--strategy.probe_unsure=true", "--strategy.split_episodes=true"]
    for round_index, (cost, flags) in enumerate([(3.0, ["--strategy.rollout_cost=3"]), (0.5, second)], 1):
        done = run_cli("adademo-record", *record_args(root, checkpoint, strategy=[*paying, *flags]))
        assert (
            f"round {round_index} plan (budgeted paying for policy episodes at {cost:g}, B=4" in done.stdout
        )
        ledger = [r for r in read_ledger(root) if r["round"] == round_index]
        assert [r["task"] for r in ledger] == ["reach-v3", "push-v3"]
        spent = sum(r["demos_added"] + r["expert_failures"] + cost * r["eval_episodes"] for r in ledger)
        assert 0 < spent <= 4 and {r["extra"]["round_cost"] for r in ledger} == {spent}
        evaluations = [e for e in read_round_evaluations(root, round_index) if e["type"] == "eval"]
        assert len(evaluations) == sum(r["eval_episodes"] for r in ledger)
        failed = {(e["task"], e["seed"]) for e in evaluations if not e["success"]}
        evaluated = {(e["task"], e["seed"]) for e in evaluations}
        new = read_episode_metadata(root)
        new = new[new["adademo/round"] == round_index]
        demos = set(zip(new.task, new["adademo/seed"], strict=True))
        assert len(demos) == len(new) == sum(r["demos_added"] for r in ledger)
        assert demos & evaluated <= failed  # at a failed episode's start, or from a new scene
        assert len(demos - evaluated) == sum(r["extra"]["fresh_demos"] for r in ledger)
        assert set(new["adademo/source"]) == {"human"}
        if round_index == 1:  # no policy episode worth its cost: four demonstrations from new scenes
            assert not evaluations and len(new) == 4
        else:  # at 0.5 a task whose failure rate may be 1/4 or more is worth its episodes: Beta(1, 1) is
            assert evaluations
    check_dataset_integrity(root)


@requires_rendering
def test_old_strategy_flags_say_their_new_spelling_and_change_nothing(recorded):
    root, checkpoint = recorded
    before = file_digests(root)
    for flag, value in (
        ("target_successes", 5),
        ("max_demos_per_task", 10),
        ("max_eval_episodes_per_task", 30),
    ):
        assert_cli_error(
            "adademo-record",
            *record_args(root, checkpoint, f"--{flag}={value}", strategy=[]),
            match=f"--{flag} moved: use --strategy.{flag}",
        )
    assert_cli_error(  # a strategy that needs demonstrations from fresh initial states needs a simulated round
        "adademo-record",
        *record_args(root, checkpoint, strategy=["--strategy.type=uniform"]),
        match="use --strategy.type=adademo or budgeted",
    )
    assert_cli_error(  # ranking sampled initial states needs a simulator
        "adademo-record",
        *record_args(
            root,
            checkpoint,
            strategy=[
                "--strategy.type=budgeted",
                "--strategy.budget=2",
                "--strategy.rollout_cost=1",
                "--strategy.rank_states=knn",
            ],
        ),
        match="rank_states=knn ranks initial states a simulator samples",
    )
    assert file_digests(root) == before


@requires_rendering
@pytest.mark.slow
def test_the_person_takes_over_where_the_policy_goes_wrong(recorded, tmp_path):
    """--demo_start=takeover: the scripted person watches the policy, takes over once it goes where the expert would
    not, and the correction is recorded from that moment: two rounds, each starting from the last."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    source, checkpoint = recorded
    root = tmp_path / "dataset"
    subprocess.run(["cp", "-r", str(source), str(root)], check=True)
    # The scripted person takes over after 5 steps of disagreement by more than 0.5 (a watchful person).
    takeover = ["--demo_start=takeover", "--teleop.takeover_threshold=0.5", "--dataset.episode_time_s=3"]
    args = record_args(root, checkpoint, *takeover)
    for round_index in (1, 2):
        run_cli("adademo-record", *args)
        evaluations = {
            (e["task"], e["seed"]): e
            for e in read_round_evaluations(root, round_index)
            if e["type"] == "eval"
        }
        eps = read_episode_metadata(root)
        new = eps[eps["adademo/round"] == round_index]
        assert len(new) > 0 and set(new["adademo/source"]) == {"correction"}
        stock = LeRobotDataset("local/robot", root=root, video_backend="pyav")
        for index, row in new.iterrows():
            failed = evaluations[(row.task, row["adademo/seed"])]  # the policy episode the person took over
            assert failed["success"] is False and failed["takeover_rule"] == "person"
            # The takeover came after the scripted person saw 5 disagreeing steps, and the correction starts there.
            assert row["adademo/start_step"] == failed["takeover_step"] == failed["steps"] >= 5
            np.testing.assert_allclose(row["adademo/start_state"], failed["takeover_state"])
            np.testing.assert_allclose(row["adademo/initial_state"], failed["initial_state"])
            first = stock[int(stock.meta.episodes[index]["dataset_from_index"])]
            np.testing.assert_allclose(
                first["observation.state"].numpy(), failed["takeover_state"], atol=1e-6
            )
        for r in (r for r in read_ledger(root) if r["round"] == round_index):
            mine = new[new.task == r["task"]]
            assert r["corrections"] == r["demos_added"] == len(mine)
            assert r["demo_frames"] == int(mine["length"].sum())
            assert r["extra"]["person_seconds"]["demonstrations"] > 0


@pytest.mark.slow
@requires_rendering
def test_bad_input_gets_one_error_and_no_change(recorded, reach_push_dataset, act_run, tmp_path):
    root, checkpoint = recorded
    before = file_digests(root)
    assert_cli_error(
        "adademo-record",
        *record_args(root, checkpoint, "--robot.type=so999_follower"),
        match="so999_follower",
    )
    assert_cli_error(
        "adademo-record",
        *record_args(root, checkpoint, "--teleop.type=no_such_leader"),
        match="no_such_leader",
    )
    sim_policy = act_run / "checkpoints" / "last" / "pretrained_model"  # trained on a suite dataset
    assert_cli_error(
        "adademo-record",
        *record_args(root, sim_policy),
        match="features do not match the robot's observations",
    )
    assert_cli_error(
        "adademo-record",
        *record_args(reach_push_dataset, checkpoint),
        match="recorded with robot 'metaworld'",
    )
    assert_cli_error(
        "adademo-record",
        *record_args(root, checkpoint, "--robot.image_size=48"),
        match="differs (dataset (32, 32, 3), robot (48, 48, 3)) (set the robot as it was recorded",
    )
    assert_cli_error(
        "adademo-record", *record_args(root, checkpoint, "--judge=keys"), match="needs the person's keys"
    )
    assert_cli_error(
        "adademo-record", *record_args(root, checkpoint, "--tasks=fly-v3"), match="not in the dataset"
    )
    assert_cli_error(
        "adademo-record", *record_args(root, checkpoint, "--demo_start=later"), match="unknown --demo_start"
    )
    assert file_digests(root) == before


@pytest.mark.parametrize("scene_state", [False, True], ids=["hand", "scene"])
def test_the_robot_view_of_a_suite_sees_what_the_simulated_robot_reads(scene_state):
    """A dataset recorded on adademo_sim continues in simulation (adademo-run) through the robot view of the
    MetaWorld suite: same feature names and shapes as the robot's, and the same readings in the same scene."""
    from adademo_lerobot.dataset.features import dataset_features
    from adademo_lerobot.lerobot_plugins.adademo_sim import JOINTS, AdademoSim
    from adademo_lerobot.lerobot_plugins.config_adademo_sim import AdademoSimConfig
    from adademo_lerobot.loop.record import robot_features
    from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

    config = AdademoSimConfig(task="push-v3", tasks="reach-v3,push-v3", camera="", scene_state=scene_state)
    robot = AdademoSim(config)
    robot.connect()
    try:
        robot.reset_scene(5)
        readings = robot.get_observation()
    finally:
        robot.disconnect()
    view = "robot_scene" if scene_state else "robot"
    suite = MetaWorldSuiteConfig(tasks="reach-v3,push-v3", view=view).build()
    mine = dataset_features(suite)
    theirs = robot_features(robot, use_video=False)
    assert mine.keys() == theirs.keys()
    for key, feature in theirs.items():
        assert (tuple(mine[key]["shape"]), mine[key]["names"]) == (tuple(feature["shape"]), feature["names"])
    env = suite.make_env("push-v3")
    obs, _ = env.reset(options={"initial_state": suite.sample_initial_state("push-v3", 5)})
    env.close()
    names = theirs["observation.state"]["names"]
    assert names[:4] == list(JOINTS)
    np.testing.assert_array_equal(obs["agent_pos"], [readings[n] for n in names])
