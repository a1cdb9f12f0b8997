"""Corrections from the point of failure (`--demo_start=takeover`) on a real dataset and a real (weak) ACT: the
expert takes over failed rollouts, the corrections are ordinary LeRobot episodes that replay exactly from their
recorded start state, and the ledger counts what they cost."""

import numpy as np
from conftest import assert_cli_error, expand, file_digests, replay, run_cli

from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.base import full_state_step, split_full_state
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def test_two_takeover_rounds_add_corrections_that_replay_exactly(dataset, ckpt):
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3"))
    common = [
        f"--policy.path={ckpt}",
        "--strategy.type=adademo",
        "--strategy.target_successes=1",
        "--strategy.max_demos_per_task=3",
    ]
    common += ["--eval.batch_size=3", "--demo_start=takeover"]
    expand(dataset, *common, "--takeover.rule=backoff", "--takeover.backoff=30")
    expand(dataset, *common, "--takeover.rule=disagreement")
    eps = read_episode_metadata(dataset)
    for round_index, rule in ((1, "backoff"), (2, "disagreement")):
        new = eps[eps["adademo/round"] == round_index]
        corrections = new["adademo/source"] == "correction"
        # With the default --takeover.fallback=initial, a takeover state the expert fails from is answered by
        # a demonstration from the failed episode's initial state (the strategy's own source, step 0).
        assert corrections.any() and (new.loc[~corrections, "adademo/source"] == "adademo").all()
        assert (new.loc[~corrections, "adademo/start_step"] == 0).all()
        evaluations = {
            (e["task"], e["seed"]): e
            for e in read_round_evaluations(dataset, round_index)
            if e["type"] == "eval"
        }
        for index, row in new.iterrows():
            failed = evaluations[(row.task, row["adademo/seed"])]  # the failed episode the correction answers
            assert failed["success"] is False
            if row["adademo/source"] == "correction":
                assert (
                    row["adademo/start_step"]
                    == failed["takeover_step"]
                    == full_state_step(row["adademo/start_state"])
                )
                np.testing.assert_array_equal(row["adademo/start_state"], failed["takeover_state"])
            # ... which started from the failed episode's initial state: the seed's, also inside the start state.
            np.testing.assert_array_equal(
                row["adademo/initial_state"], suite.sample_initial_state(row.task, row["adademo/seed"])
            )
            np.testing.assert_array_equal(
                split_full_state(row["adademo/start_state"])["initial_state"], row["adademo/initial_state"]
            )
            replay(suite, dataset, index, row)
        if (
            rule == "backoff"
        ):  # a weak policy's failed rollouts run to the step limit: the expert takes over late
            assert (new["adademo/start_step"] > 0).any()
        assert {e["takeover_rule"] for e in evaluations.values() if not e["success"]} <= {rule, "backoff"}
        for r in (r for r in read_ledger(dataset) if r["round"] == round_index):
            mine = new[new.task == r["task"]]
            fallbacks = int((mine["adademo/source"] != "correction").sum())
            assert r["corrections"] == len(mine) - fallbacks and r["demos_added"] == len(mine)
            assert r["takeover_failures"] >= fallbacks
            assert r["demo_frames"] == int(mine["length"].sum()) <= r["collection_env_steps"]
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    assert LeRobotDataset("local/demo", root=dataset).num_episodes == len(eps)  # stock LeRobot opens it
    # The paper's demonstrations start at step 0, from the whole state of their initial state, and replay from it.
    initial = eps[eps["adademo/round"] == 0]
    assert (initial["adademo/start_step"] == 0).all() and (initial["adademo/source"] == "initial").all()
    for index, row in initial.iterrows():
        np.testing.assert_array_equal(
            split_full_state(row["adademo/start_state"])["initial_state"], row["adademo/initial_state"]
        )
        replay(suite, dataset, index, row)


def test_takeover_bad_input_gets_one_error_and_no_change(dataset, ckpt, tmp_path):
    before = file_digests(dataset)

    def fails(*args, root=dataset, match):
        return assert_cli_error(
            "adademo-expand", "--dataset.repo_id=local/demo", f"--dataset.root={root}", *args, match=match
        )

    takeover = [f"--policy.path={ckpt}", "--demo_start=takeover"]
    fails(
        *takeover,
        "--strategy.type=uniform",
        match="--strategy.type=uniform collects from fresh initial states",
    )
    fails(*takeover, "--takeover.rule=random", match="unknown --takeover.rule='random'")
    fails(*takeover, "--takeover.threshold=-1", match="--takeover.threshold must be >= 0")
    fails(*takeover, "--takeover.backoff=-3", match="--takeover.backoff must be >= 0")
    fails(f"--policy.path={ckpt}", "--demo_start=midway", match="unknown --demo_start='midway'")
    assert file_digests(dataset) == before

    adroit = tmp_path / "adroit"  # its scripted experts act only from an episode's start
    run_cli(
        "adademo-collect", "--suite.type=adroit", "--suite.tasks=door", "--episodes_per_task=1",
        "--dataset.repo_id=local/adroit", f"--dataset.root={adroit}",
    )  # fmt: skip
    run_cli(
        "adademo-train", "--dataset.repo_id=local/adroit", f"--dataset.root={adroit}", "--policy.type=act",
        "--policy.dim_model=32", "--policy.dim_feedforward=64", "--policy.n_encoder_layers=1",
        "--policy.n_decoder_layers=1", "--policy.chunk_size=10", "--policy.n_action_steps=5", "--steps=1",
        "--batch_size=4", f"--output_dir={tmp_path / 'adroit_act'}",
    )  # fmt: skip
    before = file_digests(adroit)
    fails(
        f"--policy.path={tmp_path / 'adroit_act' / 'checkpoints' / 'last' / 'pretrained_model'}",
        "--demo_start=takeover",
        root=adroit,
        match="the adroit-scripted expert cannot take over mid-episode",
    )
    assert file_digests(adroit) == before
