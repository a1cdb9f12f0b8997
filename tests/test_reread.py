"""benchmarks/data_efficiency.py reread: a finished run's data and weights read again with another readout (ACT's
temporal ensembling): the copied checkpoints load in LeRobot and act by the new readout, the weights stay the
same files, the evaluations are dropped so that the run evaluates again, and a recipe that would train otherwise
is refused."""

import json
import shutil

import pytest
import yaml
from conftest import TINY_ACT_POLICY, load_benchmark, run_cli

bench = load_benchmark("data_efficiency")

# The recipe's policy as a dict (the tiny ACT of the tests), acting by temporal ensembling.
POLICY = {k.removeprefix("--policy."): yaml.safe_load(v) for k, v in (a.split("=") for a in TINY_ACT_POLICY)}
POLICY |= {"n_action_steps": 1, "temporal_ensemble_coeff": 0.01}


def finished_run(act_run, root):
    """A run folder as adademo-run leaves it: round 0 trained (adademo-train's checkpoints), evaluated."""
    shutil.copytree(act_run, root / "train" / "round-0")
    trained = root / "train" / "round-0" / "checkpoints" / "000004" / "pretrained_model"
    done = {"collect": {"result": {}}, "train-0": {"result": str(trained)}, "eval-0": {"result": {}}}
    (root / "run_state.json").write_text(json.dumps({"settings": {"seed": 0}, "done": done}))
    (root / "eval" / "round-000").mkdir(parents=True)
    return trained


def test_reread_copies_a_run_acting_by_the_recipe_s_readout(act_run, reach_push_dataset, tmp_path):
    from lerobot.configs.policies import PreTrainedConfig

    src, dst = tmp_path / "chunked" / "uniform", tmp_path / "ensembled" / "uniform"
    trained = finished_run(act_run, src)
    dst.parent.mkdir()
    bench.copy_with_readout(src, dst, POLICY)

    state = json.loads((dst / "run_state.json").read_text())
    assert list(state["done"]) == ["collect", "train-0"]  # evaluated again when the run is rerun
    copied = dst / trained.relative_to(src)
    assert state["done"]["train-0"]["result"] == str(copied) and not (dst / "eval").exists()
    for step in ("000002", "000004"):
        model = dst / "train" / "round-0" / "checkpoints" / step / "pretrained_model"
        config = PreTrainedConfig.from_pretrained(model)  # LeRobot's own checks pass
        assert (config.n_action_steps, config.temporal_ensemble_coeff) == (1, 0.01)
        assert config.chunk_size == 10 and config.dim_model == 32  # the rest as trained
        before = src / model.relative_to(dst) / "model.safetensors"
        assert (model / "model.safetensors").read_bytes() == before.read_bytes()
        trained_with = json.loads((model / "train_config.json").read_text())
        assert trained_with["policy"]["temporal_ensemble_coeff"] == 0.01
        assert str(src) not in json.dumps(trained_with)  # its paths are the copy's
    source = json.loads((src / trained.relative_to(src) / "config.json").read_text())
    assert (source["n_action_steps"], source["temporal_ensemble_coeff"]) == (
        5,
        None,
    )  # the source is untouched
    assert json.loads((dst / "reread_from.json").read_text())["from"] == str(src.resolve())

    # The copy acts by temporal ensembling in adademo-eval (through LeRobot's rollout).
    out = tmp_path / "eval"
    run_cli(
        "adademo-eval",
        f"--policy.path={copied}",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={reach_push_dataset}",
        "--episodes_per_task=2",
        f"--output_dir={out}",
    )
    assert json.loads((out / "eval_summary.json").read_text())["per_task"]

    # A recipe that trains another policy (a longer chunk) is not a readout: refused, nothing left behind.
    with pytest.raises(SystemExit, match="chunk_size"):
        bench.copy_with_readout(src, tmp_path / "ensembled" / "other", POLICY | {"chunk_size": 20})
    assert not list((tmp_path / "ensembled").glob("other*"))
