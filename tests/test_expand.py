"""adademo-expand on real datasets and a real (weak) ACT checkpoint: strategies, plan_only, ledger, crash safety."""

import json
import math
import re
import shutil
import signal
import subprocess
import time

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import BIN, TINY_ACT_POLICY, assert_cli_error, expand, file_digests, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.seeds import expansion_state_seed, fresh_state_seed
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.dataset.store import recover_interrupted_write
from adademo_lerobot.strategies import planned_demos
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

TASKS = ("reach-v3", "push-v3")


def old_files_unchanged(before: dict, after: dict) -> None:
    for rel, digest in before.items():
        if rel.startswith(("data/", "meta/episodes/")):
            assert after[rel] == digest, f"{rel} was rewritten"


def check_ledger_agrees(root, round_index):
    eps = read_episode_metadata(root)
    ledger = [r for r in read_ledger(root) if r["round"] == round_index]
    assert sorted(r["task"] for r in ledger) == sorted(TASKS)  # one record per task
    new = eps[eps["adademo/round"] == round_index]
    for r in ledger:
        assert r["demos_added"] == int((new.task == r["task"]).sum())
    assert not new.duplicated(["task", "adademo/seed"]).any()  # no state twice in a round
    return eps, new, ledger


def test_adademo_collects_only_on_failed_states_within_the_cap(dataset, ckpt):
    before = file_digests(dataset)
    expand(
        dataset,
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=5",
        "--eval.batch_size=3",
    )
    eps, new, ledger = check_ledger_agrees(dataset, 1)
    old_files_unchanged(before, file_digests(dataset))
    assert len(eps) == 6 + len(new) and (new["adademo/source"] == "adademo").all()
    evaluations = {
        (e["task"], e["seed"]): e for e in read_round_evaluations(dataset, 1) if e["type"] == "eval"
    }
    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS)))
    for _, ep in new.iterrows():
        assert evaluations[(ep.task, ep["adademo/seed"])]["success"] is False
        np.testing.assert_array_equal(
            ep["adademo/initial_state"], suite.sample_initial_state(ep.task, ep["adademo/seed"])
        )
    for r in ledger:
        assert r["demos_added"] <= 5 and r["successes"] <= 2
        assert r["eval_episodes"] == r["successes"] + r["failures"]
        assert r["failures"] == r["demos_added"] + r["expert_failures"]
        assert r["cap_hit"] == (r["demos_added"] == 5)
        # The loop stopped for one of its three reasons, and the count says which.
        if r["successes"] < 2 and not r["cap_hit"]:
            assert r["eval_bound_hit"] and r["eval_episodes"] == 2 * (2 + 5)  # the default evaluation bound
        else:
            assert not r["eval_bound_hit"] and r["eval_episodes"] <= 2 * (2 + 5)
        # The states evaluated are the loop's own samples, in order, and their cost is accounted.
        seeds = [expansion_state_seed(0, 1, r["task"], k) for k in range(r["eval_episodes"])]
        assert all((r["task"], s) in evaluations for s in seeds)
        assert r["eval_env_steps"] == sum(evaluations[(r["task"], s)]["steps"] for s in seeds)
        assert r["collection_env_steps"] > 0 and r["wall_seconds"] > 0
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    assert LeRobotDataset("local/demo", root=dataset).num_episodes == len(eps)


def test_uniform_adds_exactly_n_per_task_from_fresh_states(dataset):
    expand(dataset, "--strategy.type=uniform", "--strategy.demos_per_task=4")
    _, new, ledger = check_ledger_agrees(dataset, 1)
    for r in ledger:
        assert r["demos_added"] == 4 - r["expert_failures"] and r["eval_episodes"] == 0
        rows = new[new.task == r["task"]]
        assert set(rows["adademo/seed"]) <= {fresh_state_seed(0, 1, r["task"], d) for d in range(12)}


@pytest.mark.parametrize(
    "option",
    [
        "--strategy.rank_states=knn",
        "--strategy.rank_states=knn_fresh",
        "--strategy.split_episodes=true --demo_start=takeover --takeover.fallback=initial",
    ],
    ids=["knn", "knn_fresh", "split_takeover"],
)
def test_rollout_cost_pays_for_rollouts_from_the_budget_over_two_rounds(dataset, ckpt, option):
    """Round 2 ranks its states by the outcomes of round 1 (k-NN: evaluated and fresh states, or with knn_fresh the
    fresh ones only), or splits its budget by the posterior they give: two rounds, each within its budget counted
    in episodes (a correction is part of the rollout it corrects), every demo at a state the policy failed or
    counted as a fresh one (no rollout), and the journaled evaluations are exactly the ledger's rollouts."""
    corrections = 0
    for round_index in (1, 2):
        expand(
            dataset,
            f"--policy.path={ckpt}",
            "--strategy.type=budgeted",
            "--strategy.budget=6",
            "--strategy.rollout_cost=0.5",
            *option.split(),
            "--eval.batch_size=2",
        )
        _, new, ledger = check_ledger_agrees(dataset, round_index)
        round_corrections = int((new["adademo/source"] == "correction").sum())
        assert sum(r["corrections"] for r in ledger) == round_corrections
        corrections += round_corrections
        cost = sum(
            r["demos_added"] - r["corrections"] + r["expert_failures"] + 0.5 * r["eval_episodes"]
            for r in ledger
        )
        assert 0 < cost <= 6 and all(r["extra"]["round_cost"] == cost for r in ledger)
        evaluations = [e for e in read_round_evaluations(dataset, round_index) if e["type"] == "eval"]
        assert len(evaluations) == sum(r["eval_episodes"] for r in ledger)
        failed = {(e["task"], e["seed"]) for e in evaluations if not e["success"]}
        evaluated = {(e["task"], e["seed"]) for e in evaluations}
        demos = set(zip(new.task, new["adademo/seed"], strict=True))
        assert demos & evaluated <= failed
        assert len(demos - evaluated) == sum(r["extra"]["fresh_demos"] for r in ledger)
        if option != "--strategy.rank_states=knn":  # random evaluated states: the posterior's unbiased sample
            for r in ledger:
                seeds = [
                    expansion_state_seed(0, round_index, r["task"], k) for k in range(r["eval_episodes"])
                ]
                assert {s for t, s in evaluated if t == r["task"]} == set(seeds)
                fresh = {s for t, s in demos - evaluated if t == r["task"]}
                draws = r["extra"]["fresh_attempts"] + (8 if "knn_fresh" in option else 0)  # 8 candidates
                assert fresh <= {fresh_state_seed(0, round_index, r["task"], d) for d in range(draws)}
    assert (corrections > 0) == ("takeover" in option)  # the episode count above was tested with corrections


@pytest.mark.slow
def test_task_only_allocates_like_adademo_from_fresh_states(dataset, ckpt):
    expand(
        dataset,
        f"--policy.path={ckpt}",
        "--strategy.type=task_only",
        "--strategy.target_successes=1",
        "--strategy.max_demos_per_task=3",
        "--strategy.plan_episodes_per_task=4",
    )
    _, new, ledger = check_ledger_agrees(dataset, 1)
    for r in ledger:
        sr = r["successes"] / r["eval_episodes"]
        assert r["eval_episodes"] == 4
        assert r["planned_demos"] == (3 if sr == 0 else min(3, math.ceil(1 / sr - 1)))
        assert r["demos_added"] == r["planned_demos"] - r["expert_failures"]
        rows = new[new.task == r["task"]]
        assert set(rows["adademo/seed"]) <= {fresh_state_seed(0, 1, r["task"], d) for d in range(9)}
    assert (
        planned_demos(10, 0.5, 100) == 10
        and planned_demos(10, 0.0, 7) == 7
        and planned_demos(10, 1.0, 5) == 0
    )


def test_the_plan_names_the_tasks_whose_cap_is_lower_this_round():
    from adademo_lerobot.loop.expand import plan_header

    caps = {"door": 20, "hammer": 20, "pen": 15, "relocate": 20}
    assert plan_header(2, 5, 20, caps) == "plan for round 2 (E=5, CAP=20, pen 15); nothing collected"
    assert (
        plan_header(1, 10, 20, dict.fromkeys(caps, 20))
        == "plan for round 1 (E=10, CAP=20); nothing collected"
    )


def test_plan_only_prints_predictions_and_changes_nothing(dataset, ckpt):
    before = file_digests(dataset)
    proc = expand(
        dataset,
        f"--policy.path={ckpt}",
        "--plan_only=true",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=4",
        "--plan_episodes_per_task=3",
    )
    assert "predicted demos" in proc.stdout and "total" in proc.stdout and "nothing collected" in proc.stdout
    assert file_digests(dataset) == before


@pytest.mark.slow
def test_second_round_follows_the_first(dataset, ckpt):
    expand(dataset, "--strategy.type=uniform", "--strategy.demos_per_task=1")
    expand(
        dataset,
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=1",
        "--strategy.max_demos_per_task=2",
    )
    assert sorted({r["round"] for r in read_ledger(dataset)}) == [1, 2]
    check_ledger_agrees(dataset, 2)


@pytest.mark.parametrize(
    "demo_start",
    ["initial", pytest.param("takeover", marks=pytest.mark.slow)],
)
def test_kill_9_during_collection_then_same_command_finishes_the_round(dataset, ckpt, demo_start):
    args = [
        "--dataset.repo_id=local/demo",
        f"--dataset.root={dataset}",
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=2",
        "--strategy.max_demos_per_task=6",
        "--commit_every=1",
        "--eval.batch_size=2",
        f"--demo_start={demo_start}",
    ]
    episodes_dir = dataset / "meta" / "episodes"
    files_before = len(list(episodes_dir.rglob("*.parquet")))
    eps0 = read_episode_metadata(dataset)
    proc = subprocess.Popen(
        [str(BIN / "adademo-expand"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.time() + 300
    while len(list(episodes_dir.rglob("*.parquet"))) < files_before + 3:  # two commits done, a third begun
        assert time.time() < deadline and proc.poll() is None, "expand ended before it could be killed"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # What the kill left committed: rolling back a half-done write (as the next command does) keeps it all.
    recover_interrupted_write(dataset)
    committed = read_episode_metadata(dataset)
    committed_round_1 = set(zip(committed.task, committed["adademo/seed"], strict=True)) - set(
        zip(eps0.task, eps0["adademo/seed"], strict=True)
    )
    assert len(committed_round_1) >= 2, "the kill came after two commits"
    # Resumed with another evaluation batch, the round would evaluate other states together: refused, unchanged.
    other = [a if a != "--eval.batch_size=2" else "--eval.batch_size=3" for a in args]
    assert_cli_error("adademo-expand", *other, match="eval_batch_size: 2 -> 3")
    # So would another expert (its demonstrations would mix two experts in one round): refused as well.
    assert_cli_error(
        "adademo-expand", *args, "--collector.max_attempts=1", match="collector.max_attempts: 3 -> 1"
    )
    run_cli("adademo-expand", *args)
    eps, new, ledger = check_ledger_agrees(dataset, 1)
    # The ledger names the round's expert with its settings (its provenance, beside each episode's name).
    assert [r["collector"] for r in ledger] == [ScriptedCollectorConfig().to_dict()] * len(ledger)
    assert committed_round_1 <= set(
        zip(new.task, new["adademo/seed"], strict=True)
    )  # every committed demo is still there
    evaluations = {
        (e["task"], e["seed"]): e for e in read_round_evaluations(dataset, 1) if e["type"] == "eval"
    }
    assert all(
        evaluations[(t, s)]["success"] is False for t, s in zip(new.task, new["adademo/seed"], strict=True)
    )
    if demo_start == "takeover":  # the resumed round took over where the journaled rollouts said
        for _, row in new.iterrows():
            failed = evaluations[(row.task, row["adademo/seed"])]
            assert (
                row["adademo/source"] == "correction" and row["adademo/start_step"] == failed["takeover_step"]
            )
            np.testing.assert_array_equal(row["adademo/start_state"], failed["takeover_state"])
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    assert LeRobotDataset("local/demo", root=dataset).num_episodes == len(eps)
    assert sorted({r["round"] for r in read_ledger(dataset)}) == [1]
    # The same command again starts the next round rather than redoing this one.
    run_cli("adademo-expand", *args)
    assert sorted({r["round"] for r in read_ledger(dataset)}) == [1, 2]
    check_ledger_agrees(dataset, 2)


def test_bad_input_gets_one_clear_error_and_no_change(dataset, ckpt, tmp_path):
    before = file_digests(dataset)

    def fails(*args, root=dataset, match):
        return assert_cli_error(
            "adademo-expand", "--dataset.repo_id=local/demo", f"--dataset.root={root}", *args, match=match
        )

    fails(f"--policy.path={ckpt}", "--strategy.target_successes=0", match="target_successes")
    fails(f"--policy.path={ckpt}", "--strategy.type=greedy", match="strategy")
    # A flag is used or refused, never ignored: another strategy's setting, a list for one round, a plan flag.
    fails("--strategy.type=uniform", "--strategy.target_successes=3", match="target_successes")
    fails(
        f"--policy.path={ckpt}", "--strategy.target_successes=[5,10]", match="adademo-expand runs one round"
    )
    fails(f"--policy.path={ckpt}", "--plan_episodes_per_task=5", match="used with --plan_only")
    # A rollout cost: a number >= 0, for the strategy that uses it.
    budgeted = [f"--policy.path={ckpt}", "--strategy.type=budgeted", "--strategy.budget=4"]
    fails(*budgeted, "--strategy.rollout_cost=-1", match="rollout_cost must be a number >= 0")
    fails(*budgeted, "--strategy.rollout_cost=abc", match="rollout_cost")
    fails(*budgeted, "--strategy.rank_states=knn", match="used with --strategy.rollout_cost")
    fails(*budgeted, "--strategy.split_episodes=true", match="used with --strategy.rollout_cost")
    fails(*budgeted, "--strategy.optimism=0.9", match="used with --strategy.rollout_cost")
    fails(
        *budgeted, "--strategy.rollout_cost=1", "--strategy.optimism=1.5", match="optimism must be a quantile"
    )
    fails(
        "--strategy.type=uniform",
        "--strategy.demos_per_task=1",
        "--strategy.rollout_cost=1",
        match="rollout_cost",
    )
    fails(f"--policy.path={tmp_path / 'missing'}", match="no LeRobot checkpoint")
    fails("--strategy.type=adademo", match="--policy.path")
    with exclusive_use(
        dataset, "a test"
    ):  # another command is writing this dataset: refused, not interleaved
        fails(
            "--strategy.type=uniform",
            "--strategy.demos_per_task=1",
            match="in use by another running adademo command",
        )
    assert file_digests(dataset) == before

    three = tmp_path / "three"
    run_cli(
        "adademo-collect",
        "--suite.tasks=reach-v3,push-v3,drawer-open-v3",
        "--episodes_per_task=1",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={three}",
    )
    fails(f"--policy.path={ckpt}", root=three, match="observation.environment_state")

    plain = tmp_path / "plain"  # a LeRobot dataset of a real robot: no suite to build envs from
    shutil.copytree(dataset, plain)
    shutil.rmtree(plain / "meta" / "adademo")
    for f in (plain / "meta" / "episodes").rglob("*.parquet"):
        table = pq.read_table(f)
        pq.write_table(table.select([c for c in table.column_names if not c.startswith("adademo/")]), f)
    info = json.loads((plain / "meta" / "info.json").read_text())
    (plain / "meta" / "info.json").write_text(json.dumps({**info, "robot_type": "so101_follower"}))
    before_plain = file_digests(plain)
    fails(f"--policy.path={ckpt}", root=plain, match="--suite.type")
    assert file_digests(plain) == before_plain


def test_a_damaged_dataset_is_refused_before_anything_is_written(dataset, ckpt):
    """A truncated data file (a full disk, a killed copy): one error line naming the file, nothing written."""
    first = sorted((dataset / "data").rglob("*.parquet"))[0]
    first.write_bytes(first.read_bytes()[: first.stat().st_size // 2])
    before = file_digests(dataset)
    for args in (["--strategy.type=uniform"], [f"--policy.path={ckpt}", "--strategy.type=adademo"]):
        last = assert_cli_error(
            "adademo-expand",
            "--dataset.repo_id=local/demo",
            f"--dataset.root={dataset}",
            *args,
            match="is damaged",
        )
        assert str(first.relative_to(dataset)) in last
    assert file_digests(dataset) == before
    assert not (dataset / "meta" / "adademo" / "journal-round-001.jsonl").exists()


@pytest.mark.slow
def test_checkpoint_with_another_action_size_is_refused(dataset, tmp_path):
    """A real stock `lerobot-train` ACT whose action has 5 dims (the suite's has 4)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.state": {"dtype": "float32", "shape": (4,), "names": None},
        "observation.environment_state": {"dtype": "float32", "shape": (41,), "names": None},
        "action": {"dtype": "float32", "shape": (5,), "names": None},
    }
    other = LeRobotDataset.create("local/other", fps=80, features=features, root=tmp_path / "other")
    rng = np.random.default_rng(0)
    for _ in range(2):
        for _ in range(30):
            other.add_frame(
                {
                    "observation.state": rng.normal(size=4).astype(np.float32),
                    "observation.environment_state": rng.normal(size=41).astype(np.float32),
                    "action": rng.normal(size=5).astype(np.float32),
                    "task": "reach-v3",
                }
            )
        other.save_episode()
    other.finalize()
    out = tmp_path / "stock5"
    proc = subprocess.run(
        [
            str(BIN / "lerobot-train"),
            "--dataset.repo_id=local/other",
            f"--dataset.root={tmp_path / 'other'}",
            *TINY_ACT_POLICY,
            "--batch_size=4",
            "--steps=1",
            f"--output_dir={out}",
            "--policy.push_to_hub=false",
            "--num_workers=0",
            "--env_eval_freq=0",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    before = file_digests(dataset)
    last = assert_cli_error(
        "adademo-expand",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={dataset}",
        f"--policy.path={out / 'checkpoints/last/pretrained_model'}",
        match="action shape (5,)",
    )
    assert "(4,)" in last
    assert file_digests(dataset) == before


def test_budgeted_spends_exactly_its_budget_on_failed_states_and_records_the_posterior(dataset, ckpt):
    args = [
        f"--policy.path={ckpt}",
        "--strategy.type=budgeted",
        "--strategy.max_demos_per_task=10",
        "--eval.batch_size=3",
    ]
    expand(dataset, *args, "--strategy.budget=5")
    _, new, ledger = check_ledger_agrees(dataset, 1)
    assert (
        len(new) == 5 == sum(r["demos_added"] for r in ledger)
    )  # the weak policy fails: the expert fills it
    evaluations = {
        (e["task"], e["seed"]): e for e in read_round_evaluations(dataset, 1) if e["type"] == "eval"
    }
    assert all(
        evaluations[(t, s)]["success"] is False for t, s in zip(new.task, new["adademo/seed"], strict=True)
    )
    for r in ledger:
        assert r["strategy"] == "budgeted" and r["planned_demos"] is not None and r["extra"]["budget"] == 5
        assert r["extra"]["prior"] == [1.0, 1.0]  # no earlier round
        assert r["extra"]["posterior"] == [1 + r["successes"], 1 + r["failures"]]
    # Round 2 starts from round 1's outcomes.
    expand(dataset, *args, "--strategy.budget=4")
    _, new, ledger = check_ledger_agrees(dataset, 2)
    assert len(new) == 4
    assert all(r["extra"]["prior"] != [1.0, 1.0] for r in ledger)


def test_a_budget_picks_e_for_the_papers_strategy(dataset, ckpt):
    proc = expand(
        dataset,
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.budget=6",
        "--strategy.max_demos_per_task=3",
    )
    picked = int(re.search(r"picked E=(\d+)", proc.stdout).group(1))
    _, new, ledger = check_ledger_agrees(dataset, 1)
    assert {r["target_successes"] for r in ledger} == {picked} and len(new) <= 6


def test_budget_bad_input_gets_one_error_and_no_change(dataset, ckpt):
    before = file_digests(dataset)
    for args, match in (
        (["--strategy.type=budgeted", "--strategy.budget=0"], "--strategy.budget needs one value >= 1"),
        (["--strategy.type=budgeted"], "--strategy.budget needs one value >= 1"),
        (
            ["--strategy.type=adademo", "--strategy.budget=5", "--strategy.target_successes=3"],
            "both set the round's size",
        ),
    ):
        assert_cli_error(
            "adademo-expand",
            "--dataset.repo_id=local/demo",
            f"--dataset.root={dataset}",
            f"--policy.path={ckpt}",
            *args,
            match=match,
        )
    assert file_digests(dataset) == before
