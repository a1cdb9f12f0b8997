"""Keeping the round's successful policy rollouts as data (`--keep_successes`) on a real dataset and a real ACT
that succeeds now and then: over two rounds every successful evaluation is in the dataset once, as an
`adademo/source=policy` episode that replays to success, beside the expert's demonstrations; a killed round
resumes to the same dataset; training draws the kept rollouts with `--autonomous_weight`."""

import shutil
import signal
import subprocess
import time

import numpy as np
import pandas as pd
import pytest
from conftest import BIN, assert_cli_error, file_digests, replay, run_cli

from adademo_lerobot.dataset.interventions import imitation_units
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.store import recover_interrupted_write
from adademo_lerobot.samplers import frame_weights, make_sampling_scheme
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def args(root, ckpt, *extra):
    return [
        "--dataset.repo_id=local/demo",
        f"--dataset.root={root}",
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=20",
        "--strategy.max_eval_episodes_per_task=40",
        "--eval.batch_size=2",
        "--keep_successes=true",
        *extra,
    ]


def successes(root, round_index) -> list[int]:
    return [
        e["seed"] for e in read_round_evaluations(root, round_index) if e["type"] == "eval" and e["success"]
    ]


def test_two_rounds_keep_every_successful_rollout_once_and_it_replays(reach, tmp_path):
    source, ckpt = reach
    root = tmp_path / "ds"
    shutil.copytree(source, root)
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3"))
    for round_index in (1, 2):
        run_cli("adademo-expand", *args(root, ckpt))
        eps = read_episode_metadata(root)
        new = eps[eps["adademo/round"] == round_index]
        kept = new[new["adademo/source"] == "policy"]
        won = successes(root, round_index)
        assert len(won) >= 1, "the ACT succeeded at least once"
        # Every successful evaluation once, in the order it was evaluated; the expert's answer the failures.
        assert kept["adademo/seed"].tolist() == won
        assert (kept["adademo/collector"] == "").all()
        experts = new[new["adademo/source"] == "adademo"]
        assert not set(experts["adademo/seed"]) & set(won)
        [ledger] = [r for r in read_ledger(root) if r["round"] == round_index]
        assert ledger["policy_episodes_kept"] == len(kept) and ledger["demos_added"] == len(experts)
        assert ledger["successes"] == len(kept)  # adademo stops at E successes: all of them kept
        for index, row in kept.iterrows():
            replay(suite, root, index, row)
            assert row["length"] == next(
                e["steps"]
                for e in read_round_evaluations(root, round_index)
                if e["type"] == "eval" and e["seed"] == row["adademo/seed"]
            )
    # Round 2 drew other states than round 1.
    eps = read_episode_metadata(root)
    policy = eps[eps["adademo/source"] == "policy"]
    assert set(policy[policy["adademo/round"] == 1]["adademo/seed"]).isdisjoint(
        policy[policy["adademo/round"] == 2]["adademo/seed"]
    )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    assert LeRobotDataset("local/demo", root=root).num_episodes == len(eps)

    # Training draws the kept rollouts only with --autonomous_weight > 0, each as that many demonstrations.
    def weights(w: float) -> pd.Series:
        units = imitation_units(root, eps, w)
        frames = frame_weights(make_sampling_scheme("trajectory", 0.0, 1), units, int(eps["length"].sum()))
        return pd.Series(
            [frames[a:b].sum() for a, b in zip(eps.dataset_from_index, eps.dataset_to_index, strict=True)],
            index=eps.index,
        )

    is_policy = eps["adademo/source"] == "policy"
    assert (weights(0.0)[is_policy] == 0).all() and (weights(0.0)[~is_policy] > 0).all()
    half = weights(0.5)
    np.testing.assert_allclose(half[is_policy], half[~is_policy].iloc[0] / 2)
    np.testing.assert_allclose(half.sum(), 1.0)


def test_kept_rollouts_in_a_dagger_dataset_are_the_policys_frames(reach, tmp_path):
    """On a dataset with LeRobot's `intervention` frames (DAgger data), a kept rollout's frames are the policy's
    own (False), so training leaves them out at --autonomous_weight=0 as it does without the flags; the
    expert's demonstrations are the person's (True)."""
    from lerobot.datasets.dataset_tools import add_features
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from adademo_lerobot.dataset.interventions import intervention_flags

    source, ckpt = reach
    root = tmp_path / "dagger"
    frames = LeRobotDataset("local/demo", root=source).num_frames
    flag = {"dtype": "bool", "shape": [1], "names": None}
    add_features(
        LeRobotDataset("local/demo", root=source),
        {"intervention": (np.ones((frames, 1), dtype=bool), flag)},
        output_dir=root,
        repo_id="local/demo",
    )
    # LeRobot 0.6.1's add_features writes no per-episode stats for the feature it adds, which any append (LeRobot's
    # own too) then makes unreadable: refused before anything is written.
    before = file_digests(root)
    assert_cli_error("adademo-expand", *args(root, ckpt), match="no per-episode stats for intervention")
    assert file_digests(root) == before
    # A DAgger dataset recorded by lerobot-rollout has them: give them here.
    import pyarrow as pa
    import pyarrow.parquet as pq

    for path in (root / "meta" / "episodes").rglob("*.parquet"):
        table = pq.read_table(path)
        n = len(table)
        ones = pa.array([[1.0]] * n, pa.list_(pa.float64()))
        stats = {
            f"stats/intervention/{k}": ones for k in ("min", "max", "mean", "q01", "q10", "q50", "q90", "q99")
        }
        stats["stats/intervention/std"] = pa.array([[0.0]] * n, pa.list_(pa.float64()))
        lengths = [[int(x)] for x in table.column("length").to_pylist()]
        stats["stats/intervention/count"] = pa.array(lengths, pa.list_(pa.int64()))
        for name, column in stats.items():
            table = table.append_column(name, column)
        pq.write_table(table, path)
    run_cli("adademo-expand", *args(root, ckpt))
    eps = read_episode_metadata(root)
    flags = intervention_flags(root)
    new = eps[eps["adademo/round"] == 1]
    kept, experts = new[new["adademo/source"] == "policy"], new[new["adademo/source"] == "adademo"]
    assert len(kept) >= 1 and len(experts) >= 1
    for rows, person in ((kept, False), (experts, True)):
        for a, b in zip(rows["dataset_from_index"], rows["dataset_to_index"], strict=True):
            assert (flags[a:b] == person).all()
    units = imitation_units(root, eps, 0.0)
    assert not set(kept.index) & set(units.index) and set(experts.index) <= set(units.index)
    assert LeRobotDataset("local/demo", root=root).num_episodes == len(eps)


@pytest.mark.slow  # the default suite's budget; test_expand's kill -9 test resumes a round by default
def test_a_killed_round_resumes_to_the_dataset_an_uninterrupted_round_makes(reach, tmp_path):
    """Killed once a success is journaled and before anything of the round is committed (one commit at the
    task's end): the rerun runs the journaled successes again and keeps them, in the same order."""
    source, ckpt = reach
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    shutil.copytree(source, whole)
    shutil.copytree(source, killed)
    run_cli("adademo-expand", *args(whole, ckpt, "--commit_every=100"))
    journal = killed / "meta" / "adademo" / "journal-round-001.jsonl"
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *args(killed, ckpt, "--commit_every=100")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 300
    while not (journal.is_file() and '"success": true' in journal.read_text()):
        assert time.time() < deadline and proc.poll() is None, "expand ended before a success was journaled"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    recover_interrupted_write(killed)
    assert len(read_episode_metadata(killed)) == 10, "nothing of the round was committed before the kill"
    run_cli("adademo-expand", *args(killed, ckpt, "--commit_every=100"))
    columns = ["task", "length", "adademo/seed", "adademo/round", "adademo/source"]
    pd.testing.assert_frame_equal(
        read_episode_metadata(killed)[columns], read_episode_metadata(whole)[columns]
    )

    def frames(root):
        return pd.concat(pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet")))

    pd.testing.assert_frame_equal(frames(killed), frames(whole))


@pytest.mark.slow  # a killed round with kept rollouts: the test above, by default
def test_a_killed_round_of_the_loop_that_pays_for_rollouts_resumes_to_the_same_dataset(reach, tmp_path):
    """The budgeted strategy with a rollout cost (its own loop over the round: evaluate, demonstrate from fresh
    states, probe), killed once rollouts are journaled: the rerun ends with the dataset and the ledger row of an
    uninterrupted round."""
    source, ckpt = reach
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    shutil.copytree(source, whole)
    shutil.copytree(source, killed)
    paying = [
        "--dataset.repo_id=local/demo", f"--policy.path={ckpt}", "--strategy.type=budgeted",
        "--strategy.budget=10", "--strategy.max_demos_per_task=10", "--strategy.rollout_cost=1",
        "--strategy.probe_unsure=true", "--strategy.split_episodes=true", "--eval.batch_size=2",
        "--commit_every=100",
    ]  # fmt: skip
    run_cli("adademo-expand", *paying, f"--dataset.root={whole}")
    journal = killed / "meta" / "adademo" / "journal-round-001.jsonl"
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *paying, f"--dataset.root={killed}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 300
    while not (journal.is_file() and journal.read_text().count('"type": "eval"') >= 2):
        assert time.time() < deadline and proc.poll() is None, "expand ended before rollouts were journaled"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    recover_interrupted_write(killed)
    run_cli("adademo-expand", *paying, f"--dataset.root={killed}")
    columns = ["task", "length", "adademo/seed", "adademo/round", "adademo/source"]
    pd.testing.assert_frame_equal(
        read_episode_metadata(killed)[columns], read_episode_metadata(whole)[columns]
    )
    keys = ("demos_added", "eval_episodes", "successes", "failures", "expert_failures")
    assert [{k: r[k] for k in keys} for r in read_ledger(killed)] == [
        {k: r[k] for k in keys} for r in read_ledger(whole)
    ]
    assert read_ledger(whole)[0]["eval_episodes"] >= 1  # the round did pay for rollouts


def test_keep_successes_with_a_strategy_that_runs_no_rollout_is_refused(reach, tmp_path):
    source, ckpt = reach
    before = file_digests(source)
    assert_cli_error(
        "adademo-expand",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={source}",
        "--strategy.type=uniform",
        "--strategy.demos_per_task=1",
        "--keep_successes=true",
        match="--keep_successes",
    )
    assert_cli_error(
        "adademo-expand", *args(source, ckpt, "--plan_only=true"), match="--plan_only collects nothing"
    )
    assert file_digests(source) == before
