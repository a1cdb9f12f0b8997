"""The plugin of docs/lerobot-env.md, "Write your own plugin" (examples/lerobot_env_example), run as a user would:
installed as a `lerobot_env_*` distribution, collected with its callable expert, replayed from its seeds in its
own env, one AdaDemo round; and every way a plugin can be incomplete is one `error:` line with nothing written
(the incomplete ones: examples/lerobot_env_example_broken). Skipped with a reason where the examples are not
installed; setup.sh installs them and CI must run these."""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_ACT_POLICY, file_digests, run_cli

from adademo_lerobot.dataset.metadata import read_episode_metadata

if any(
    importlib.util.find_spec(name) is None for name in ("lerobot_env_example", "lerobot_env_example_broken")
):
    if os.environ.get("CI") == "true":
        pytest.fail("CI must run the plugin example's tests: examples/lerobot_env_example* are not installed")
    pytest.skip(
        "the plugin examples are not installed (pip install --no-deps -e examples/lerobot_env_example "
        "-e examples/lerobot_env_example_broken)",
        allow_module_level=True,
    )

ROOT = Path(__file__).resolve().parents[1]
TASK = "PointReach-v0"
EXAMPLE = ["--suite.type=lerobot_env", "--suite.env.type=example"]
EXPERT = ["--collector.type=callable", "--collector.entry=lerobot_env_example.expert:reach"]


def refused(command: str, *args: str, match: str, written: Path) -> str:
    """One `error:` line naming the problem, exit code 2, no traceback, and `written` not created."""
    proc = run_cli(command, *args, check=False)
    last = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else ""
    assert proc.returncode == 2 and last.startswith("error: ") and match in last, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert not written.exists()
    return last


def test_the_docs_show_the_example_as_it_is():
    """docs/lerobot-env.md shows every file of the example whole, so that the docs alone make a plugin."""
    doc = (ROOT / "docs" / "lerobot-env.md").read_text()
    example = ROOT / "examples" / "lerobot_env_example"
    files = [
        "pyproject.toml",
        *(f"lerobot_env_example/{n}.py" for n in ("__init__", "config", "env", "expert")),
    ]
    for name in files:
        assert (
            f"```{'toml' if name.endswith('toml') else 'python'}\n{(example / name).read_text()}```" in doc
        ), name


@pytest.fixture(scope="module")
def example_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("example") / "ds"
    run_cli(
        "adademo-collect", *EXAMPLE, *EXPERT, "--episodes_per_task=4", "--dataset.repo_id=local/example",
        f"--dataset.root={root}",
    )  # fmt: skip
    return root


def test_every_episode_replays_from_its_seed_in_the_plugins_own_env(example_dataset, monkeypatch, tmp_path):
    # Importing the plugin (LeRobot, torch) sets TORCHINDUCTOR_CACHE_DIR unless it is set; set here, it is undone
    # after the test: else conftest would run every later command as a plain subprocess, not a fork of its server.
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "inductor"))
    import gymnasium as gym
    import lerobot_env_example  # noqa: F401  (registers the gym ids)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    eps = read_episode_metadata(example_dataset)
    assert len(eps) == 4 and set(eps["adademo/collector"]) == {"callable:lerobot_env_example.expert:reach"}
    suite = json.loads((example_dataset / "meta" / "adademo" / "suite.json").read_text())
    assert suite["tasks"] == TASK and suite["env"]["type"] == "example" and suite["max_episode_steps"] == 50
    env = gym.make(f"lerobot_env_example/{TASK}")
    for index, row in eps.iterrows():
        kind, seed = row["adademo/initial_state"]
        assert kind == 1.0 and seed == int(seed)  # a reset seed, held exactly
        first, _ = env.reset(seed=int(seed))
        env.reset(seed=int(seed) + 1)
        obs, _ = env.reset(seed=int(seed))
        for key in first:  # the same seed gives the same initial observation
            np.testing.assert_array_equal(obs[key], first[key])
        ds = LeRobotDataset("local/example", root=example_dataset, episodes=[index])
        state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.state"]])
        env_state = np.stack([np.asarray(x) for x in ds.hf_dataset["observation.environment_state"]])
        actions = np.stack([np.asarray(x) for x in ds.hf_dataset["action"]])
        succeeded = False
        for t, action in enumerate(actions):
            np.testing.assert_allclose(obs["agent_pos"], state[t], atol=1e-6)
            np.testing.assert_allclose(obs["environment_state"], env_state[t, :2], atol=1e-6)
            obs, _, _, _, info = env.step(action)
            succeeded |= info["is_success"]
        assert succeeded, f"episode {index} does not reach the goal on replay"
        assert np.all(env_state[:, 2] == 1.0)  # the task one-hot, appended as in every suite


def test_one_adademo_round_on_the_plugin(example_dataset, tmp_path):
    """`adademo-run` from the dataset (its suite comes with it, its expert does not), one tiny round."""
    run_dir = tmp_path / "run"
    tiny = [
        "--rounds=1", "--strategy.type=adademo", "--strategy.target_successes=1", "--strategy.max_demos_per_task=2",
        *(f"--train.{flag[2:]}" for flag in TINY_ACT_POLICY), "--train.batch_size=8", "--train.steps=4",
        "--train.save_freq=4", "--eval.episodes_per_task=3", "--eval.batch_size=3",
    ]  # fmt: skip
    before = file_digests(example_dataset)
    error = refused(
        "adademo-run", f"--run_dir={run_dir}", f"--dataset.root={example_dataset}", *tiny,
        match="no scripted expert for suite 'lerobot_env'", written=run_dir,
    )  # fmt: skip
    for expert in ("--collector.type=callable", "--collector.type=policy", "a dataset keeps its suite"):
        assert expert in error
    # An expert built on the scripted ones (adademo_lerobot_example's, when installed) needs one too: not offered.
    assert "--collector.type=smoothed" not in error and "--collector.type=scripted" not in error
    assert (
        "--collector.type=planner" not in error
    )  # it needs a suite that restores any state; this one cannot
    assert file_digests(example_dataset) == before
    run_cli("adademo-run", f"--run_dir={run_dir}", f"--dataset.root={example_dataset}", *EXPERT, *tiny)
    eps = read_episode_metadata(run_dir / "dataset")
    new = eps[eps["adademo/round"] == 1]
    assert len(new) > 0 and (new["adademo/source"] == "adademo").all()
    assert len(list((run_dir / "eval").glob("round-*/eval_summary.json"))) == 2
    assert (run_dir / "report" / "report.md").exists()


def test_a_task_id_with_its_namespace_is_the_task(tmp_path):
    root = tmp_path / "ds"
    run_cli(
        "adademo-collect", *EXAMPLE, f"--suite.tasks=lerobot_env_example/{TASK}", *EXPERT, "--episodes_per_task=1",
        "--dataset.repo_id=local/x", f"--dataset.root={root}",
    )  # fmt: skip
    assert json.loads((root / "meta" / "adademo" / "suite.json").read_text())["tasks"] == TASK


BAD_INPUT = {
    "unknown env type": (
        ["--suite.env.type=exampel"],
        "unknown --suite.env.type='exampel' (did you mean example?)",
    ),
    "unknown task": (
        ["--suite.env.type=example", "--suite.tasks=PointRaech-v0"],
        "did you mean PointReach-v0",
    ),
    "task in another namespace": (
        ["--suite.env.type=example", f"--suite.tasks=gym_example/{TASK}"],
        f"give the task without its namespace: --suite.tasks={TASK}",
    ),
    "constructor refuses a field": (
        ["--suite.env.type=example", "--suite.env.tolerance=-1"],
        "ValueError: tolerance must be > 0, got -1.0 (at env.py:",
    ),
    # The broken variants (examples/lerobot_env_example_broken), each missing one thing a plugin must provide.
    "no package_name": (
        ["--suite.env.type=example_default_package_name"],
        "does not define package_name, so LeRobot imports 'gym_example_default_package_name', which does not exist",
    ),
    "wrong package_name": (
        ["--suite.env.type=example_wrong_package_name"],
        "package_name must return the namespace of the gym ids, 'lerobot_env_example'",
    ),
    "no gym_kwargs": (["--suite.env.type=example_no_gym_kwargs"], "does not define gym_kwargs"),
    "action space not a Box": (
        ["--suite.env.type=example_discrete"],
        "has the action space Discrete(4): the suite needs a gymnasium.spaces.Box",
    ),
}


@pytest.mark.parametrize("case", BAD_INPUT)
def test_an_incomplete_plugin_or_bad_flag_is_one_error_line(case, tmp_path, monkeypatch):
    monkeypatch.setenv("EXAMPLE_PLUGIN_BROKEN_VARIANTS", "1")
    flags, match = BAD_INPUT[case]
    root = tmp_path / "ds"
    refused(
        "adademo-collect", "--suite.type=lerobot_env", *flags, *EXPERT, "--episodes_per_task=1",
        "--dataset.repo_id=local/x", f"--dataset.root={root}", match=match, written=root,
    )  # fmt: skip


def test_a_builtin_env_whose_package_is_missing_is_one_error_line(tmp_path):
    if importlib.util.find_spec("gym_pusht") is not None:
        pytest.skip("gym_pusht is installed here")
    root = tmp_path / "ds"
    refused(
        "adademo-collect", "--suite.type=lerobot_env", "--suite.env.type=pusht", "--episodes_per_task=1",
        "--dataset.repo_id=local/x", f"--dataset.root={root}",
        match="the pusht env needs the package 'gym_pusht', which is not installed: pip install gym-pusht",
        written=root,
    )  # fmt: skip
