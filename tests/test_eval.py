"""adademo-eval: batched rollouts from exact initial states with real checkpoints."""

import json

import numpy as np
import pandas as pd
import pytest
from conftest import assert_cli_error, run_cli

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.core.seeds import evaluation_seeds
from adademo_lerobot.dataset.layout import SUITE_FILE
from adademo_lerobot.evaluation.policy import load_policy
from adademo_lerobot.evaluation.rollouts import BatchedEvaluator
from adademo_lerobot.loop.evaluate import suite_to_evaluate
from adademo_lerobot.suites import AdroitSuiteConfig, make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def test_eval_cli_writes_records_and_success_rates(act_run, reach_push_dataset, tmp_path):
    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    out = tmp_path / "eval"
    proc = run_cli(
        "adademo-eval",
        f"--policy.path={ckpt}",
        f"--dataset.root={reach_push_dataset}",
        "--episodes_per_task=3",
        "--eval.batch_size=2",
        "--seed=5",
        f"--output_dir={out}",
    )
    assert "reach-v3" in proc.stdout and "average" in proc.stdout
    records = pd.read_parquet(out / "eval_episodes.parquet")
    assert len(records) == 6
    assert {"task", "seed", "initial_state", "success", "steps", "sum_reward"} <= set(records.columns)
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    for task in ("reach-v3", "push-v3"):
        rows = records[records.task == task]
        assert list(rows.seed) == evaluation_seeds(5, task, 3)
        for _, r in rows.iterrows():
            np.testing.assert_array_equal(
                np.asarray(r.initial_state), suite.sample_initial_state(task, r.seed)
            )
            assert 1 <= r.steps <= 300
    summary = json.loads((out / "eval_summary.json").read_text())
    per_task = {row["task"]: row for row in summary["per_task"]}
    for task in ("reach-v3", "push-v3"):
        assert per_task[task]["successes"] == int(records[records.task == task].success.sum())
    assert summary["env_steps"] == int(records.steps.sum())

    # With a dataset, --suite.tasks picks a subset of its tasks and --suite.max_episode_steps the step limit.
    subset = tmp_path / "subset"
    run_cli(
        "adademo-eval",
        f"--policy.path={ckpt}",
        f"--dataset.root={reach_push_dataset}",
        "--suite.tasks=push-v3",
        "--suite.max_episode_steps=7",
        "--episodes_per_task=3",
        "--seed=5",
        f"--output_dir={subset}",
    )
    push = pd.read_parquet(subset / "eval_episodes.parquet")
    assert set(push.task) == {"push-v3"} and list(push.seed) == evaluation_seeds(5, "push-v3", 3)
    assert push.steps.max() <= 7 and push.steps.max() < records[records.task == "push-v3"].steps.max()


def test_eval_runs_a_stock_lerobot_train_checkpoint(stock_act_checkpoint, reach_push_dataset, tmp_path):
    out = tmp_path / "stock_eval"
    run_cli(
        "adademo-eval",
        f"--policy.path={stock_act_checkpoint}",
        f"--dataset.root={reach_push_dataset}",
        "--episodes_per_task=2",
        "--eval.batch_size=2",
        f"--output_dir={out}",
    )
    records = pd.read_parquet(out / "eval_episodes.parquet")
    assert len(records) == 4 and set(records.task) == {"reach-v3", "push-v3"}


def test_eval_reads_a_checkpoint_by_another_readout(act_run, reach_push_dataset, tmp_path):
    """--policy.n_action_steps/--policy.temporal_ensemble_coeff: the same weights acting by ACT's temporal
    ensembling, exactly as a checkpoint whose config.json says so, and not as the checkpoint itself acts."""
    import shutil

    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    stored = (ckpt / "config.json").read_text()
    out = tmp_path / "eval"
    ensembled = ["--policy.n_action_steps=1", "--policy.temporal_ensemble_coeff=0.01"]
    common = [f"--policy.path={ckpt}", f"--dataset.root={reach_push_dataset}", "--episodes_per_task=2"]
    run_cli("adademo-eval", *common, *ensembled, "--seed=5", f"--output_dir={out}")
    summary = json.loads((out / "eval_summary.json").read_text())
    assert summary["readout"] == {"n_action_steps": 1, "temporal_ensemble_coeff": 0.01}
    assert summary["policy_path"] == str(ckpt) and (ckpt / "config.json").read_text() == stored
    linked = out / "policy_readout" / "model.safetensors"
    assert linked.is_symlink() and linked.resolve() == (ckpt / "model.safetensors").resolve()
    record = json.loads((out / "policy_readout" / "readout.json").read_text())
    assert record == {"from": str(ckpt.resolve()), "readout": summary["readout"]}

    # The same episodes as a copy of the checkpoint with its config.json edited by hand; others than its own.
    edited = tmp_path / "edited"
    shutil.copytree(ckpt, edited)
    config = json.loads(stored) | {"n_action_steps": 1, "temporal_ensemble_coeff": 0.01}
    (edited / "config.json").write_text(json.dumps(config))
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    records = pd.read_parquet(out / "eval_episodes.parquet")
    for task in ("reach-v3", "push-v3"):
        seeds = evaluation_seeds(5, task, 2)
        rows = records[records.task == task]
        by_hand = BatchedEvaluator(suite, load_policy(edited), batch_size=2).run(task, seeds)
        outcomes = list(rows[["seed", "success", "steps"]].itertuples(index=False, name=None))
        assert [(r.seed, r.success, r.steps) for r in by_hand] == outcomes
        np.testing.assert_allclose([r.sum_reward for r in by_hand], rows.sum_reward, rtol=1e-3)
        own = BatchedEvaluator(suite, load_policy(ckpt), batch_size=2).run(task, seeds)
        assert not np.allclose([r.sum_reward for r in own], rows.sum_reward, rtol=1e-3)

    # Values LeRobot's config refuses: one line, nothing written; a second evaluation replaces its readout folder.
    bad = tmp_path / "bad"
    for flags, match in [
        (["--policy.temporal_ensemble_coeff=0.01"], "must be 1 when using temporal ensembling"),
        (["--policy.n_action_steps=11"], "The chunk size is the upper bound"),
        (["--policy.n_action_steps=0"], "--policy.n_action_steps must be >= 1, got 0"),
    ]:
        assert_cli_error("adademo-eval", *common, *flags, f"--output_dir={bad}", match=match)
    assert not bad.exists()
    run_cli("adademo-eval", *common, "--policy.n_action_steps=2", f"--output_dir={out}")
    assert json.loads((out / "policy_readout" / "config.json").read_text())["n_action_steps"] == 2
    assert not list(out.glob("policy_readout.*"))
    # A folder of that name that is not ours, or the readout folder as the policy to read: refused, kept.
    assert_cli_error(
        "adademo-eval", *common[1:], f"--policy.path={out / 'policy_readout'}", "--policy.n_action_steps=3",
        f"--output_dir={out}", match="is inside",
    )  # fmt: skip
    (bad / "policy_readout").mkdir(parents=True)
    (bad / "policy_readout" / "notes.txt").write_text("mine")
    assert_cli_error(
        "adademo-eval", *common, "--policy.n_action_steps=2", f"--output_dir={bad}", match="not a readout"
    )
    assert sorted(p.relative_to(bad).as_posix() for p in bad.rglob("*")) == [
        "policy_readout",
        "policy_readout/notes.txt",
    ]


def test_a_readout_the_policy_cannot_act_by_is_refused(tmp_path):
    """Diffusion has no temporal ensembling, and predicts horizon - n_obs_steps + 1 actions from the current step
    (LeRobot would run fewer than asked without a word)."""
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    from adademo_lerobot.evaluation.policy import check_readout

    checkpoint = tmp_path / "diffusion"
    checkpoint.mkdir()
    DiffusionConfig(horizon=16, n_obs_steps=2, n_action_steps=8)._save_pretrained(checkpoint)
    from safetensors.numpy import save_file

    save_file(
        {"x": np.zeros(1, dtype=np.float32)}, checkpoint / "model.safetensors"
    )  # only the config is read
    with pytest.raises(AdaDemoError, match="a diffusion policy has no such setting"):
        check_readout(checkpoint, {"temporal_ensemble_coeff": 0.01}, tmp_path / "out")
    with pytest.raises(AdaDemoError, match="this policy predicts 15 actions .* pass at most 15"):
        check_readout(checkpoint, {"n_action_steps": 16}, tmp_path / "out")
    check_readout(checkpoint, {"n_action_steps": 15}, tmp_path / "out")
    assert list(tmp_path.iterdir()) == [checkpoint]


def test_batching_does_not_change_outcomes(act_run):
    """Each sub-env starts from its own requested state: batch size 3 and batch size 1 agree episode by episode."""
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    loaded = load_policy(act_run / "checkpoints" / "last" / "pretrained_model")
    seeds = evaluation_seeds(0, "reach-v3", 3)
    evaluator = BatchedEvaluator(suite, loaded, batch_size=3)
    batched = evaluator.run("reach-v3", seeds)
    evaluator.run("push-v3", evaluation_seeds(0, "push-v3", 1))
    assert list(evaluator._pools) == ["push-v3"]  # the reach envs were closed: one task's envs at a time
    single = BatchedEvaluator(suite, loaded, batch_size=1).run("reach-v3", seeds)
    assert [(r.seed, r.success, r.steps) for r in batched] == [(r.seed, r.success, r.steps) for r in single]
    # Batched matmuls round differently in float32's last bits; returns agree to well under 0.1%.
    np.testing.assert_allclose([r.sum_reward for r in batched], [r.sum_reward for r in single], rtol=1e-3)


def test_chunked_evaluation_equals_lerobots_rollout(act_run):
    """The fast path (action chunks asked for when ACT would ask) gives exactly LeRobot's rollout() episodes."""
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3", max_episode_steps=60))
    loaded = load_policy(act_run / "checkpoints" / "last" / "pretrained_model")
    seeds = evaluation_seeds(3, "push-v3", 4)
    fast = BatchedEvaluator(suite, loaded, batch_size=3)
    stock = BatchedEvaluator(suite, loaded, batch_size=3, chunked=False)
    assert fast.chunked and not stock.chunked
    assert fast.run("push-v3", seeds) == stock.run(
        "push-v3", seeds
    )  # seeds, successes, steps, returns: all equal
    assert fast.env_steps == stock.env_steps > 0


def test_eval_bad_input(act_run, reach_push_dataset, tmp_path):
    def fails(*args, match):
        return assert_cli_error("adademo-eval", *args, match=match)

    ckpt = act_run / "checkpoints" / "last" / "pretrained_model"
    fails(
        f"--policy.path={tmp_path / 'nothing'}",
        "--suite.tasks=reach-v3,push-v3",
        f"--output_dir={tmp_path}/o",
        match="no LeRobot checkpoint",
    )
    # Suite of 3 tasks: the one-hot (and so observation.environment_state) is one longer than the checkpoint's.
    fails(
        f"--policy.path={ckpt}",
        "--suite.tasks=reach-v3,push-v3,drawer-open-v3",
        f"--output_dir={tmp_path}/o",
        match="do not match the suite's observations and actions: observation.environment_state shape (41,) in "
        "the checkpoint vs (42,) in the suite's",
    )
    # A dataset's suite decides; suite flags that contradict it are refused, not ignored.
    dataset = f"--dataset.root={reach_push_dataset}"
    common = [f"--policy.path={ckpt}", dataset, f"--output_dir={tmp_path}/o"]
    fails(*common, "--suite.tasks=window-open-v3", match="window-open-v3 not in the dataset's tasks")
    fails(*common, "--suite.obs_type=pixels_state", match="--suite.obs_type=pixels_state contradicts")
    fails(*common, "--suite.type=fetch", match="the dataset's suite is metaworld")
    assert not (tmp_path / "o").exists()


def test_eval_reads_task_short_names_in_the_datasets_suite(tmp_path):
    """`--suite.tasks=hammer` on an Adroit dataset picks AdroitHandHammer-v1, with or without --suite.type (the
    default type is MetaWorld's: tasks and the step limit alone are read in the dataset's suite)."""
    stored = AdroitSuiteConfig(tasks="AdroitHandDoor-v1,AdroitHandHammer-v1,AdroitHandPen-v1")
    (tmp_path / SUITE_FILE).parent.mkdir(parents=True)
    (tmp_path / SUITE_FILE).write_text(stored.to_json())
    suite, tasks = suite_to_evaluate(str(tmp_path), AdroitSuiteConfig(tasks="hammer,door"))
    assert tasks == ["AdroitHandHammer-v1", "AdroitHandDoor-v1"] and suite.type == "adroit"
    suite, tasks = suite_to_evaluate(str(tmp_path), MetaWorldSuiteConfig(tasks="pen", max_episode_steps=50))
    assert tasks == ["AdroitHandPen-v1"] and (suite.type, suite.max_episode_steps) == ("adroit", 50)
    with pytest.raises(AdaDemoError, match="AdroitHandRelocate-v1 not in the dataset's tasks"):
        suite_to_evaluate(str(tmp_path), AdroitSuiteConfig(tasks="relocate"))
    with pytest.raises(AdaDemoError, match="--suite.type=metaworld but the dataset's suite is adroit"):
        suite_to_evaluate(str(tmp_path), MetaWorldSuiteConfig(tasks="pen", obs_type="pixels_state"))
