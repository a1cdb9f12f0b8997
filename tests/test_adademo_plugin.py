"""A strategy and an expert from a package of their own (docs/extending.md, "Your own package"):
examples/adademo_lerobot_example, installed as a user would (setup.sh installs it), is found by every command, its
strategy runs rounds and its expert records demonstrations like built-in ones, and a plugin that fails to import is
one `error:` line that names it."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_cli_error, episode_frames, expand, file_digests, run_cli, stock_episodes

from adademo_lerobot.collectors.metaworld_scripted import scripted_policy
from adademo_lerobot.core.plugins import plugin_names
from adademo_lerobot.core.seeds import expansion_state_seed
from adademo_lerobot.dataset.ledger import read_ledger, read_round_evaluations
from adademo_lerobot.dataset.metadata import read_episode_metadata
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig

if importlib.util.find_spec("adademo_lerobot_example") is None:
    if os.environ.get("CI") == "true":
        pytest.fail(
            "CI must run the strategy plugin's tests: examples/adademo_lerobot_example is not installed"
        )
    pytest.skip(
        "the plugin example is not installed (pip install --no-deps -e examples/adademo_lerobot_example)",
        allow_module_level=True,
    )

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "adademo_lerobot_example"
TASKS = ["reach-v3", "push-v3"]
ROLLOUTS = 4


def test_the_docs_show_the_plugin_as_it_is():
    """docs/extending.md shows every file of the example whole, so that the docs alone make a plugin."""
    doc = (ROOT / "docs" / "extending.md").read_text()
    for name, fence in (
        ("pyproject.toml", "toml"),
        ("adademo_lerobot_example/__init__.py", "python"),
        ("adademo_lerobot_example/smoothed.py", "python"),
    ):
        assert f"```{fence}\n{(EXAMPLE / name).read_text()}```" in doc, name


def test_the_installed_example_is_found_by_its_distribution_and_nothing_else_is():
    names = plugin_names(sys.path)
    assert "adademo_lerobot_example" in names
    # Our own distribution and LeRobot's plugins (lerobot_env_adademo, ...) are not ours to import as plugins.
    assert all(n.startswith("adademo_lerobot_") for n in names) and "adademo_lerobot" not in names


def test_two_rounds_of_a_plugin_strategy_demonstrate_at_exactly_its_failed_states(dataset, ckpt):
    for round_index in (1, 2):
        expand(
            dataset,
            f"--policy.path={ckpt}",
            "--strategy.type=every_failure",
            f"--strategy.rollouts_per_task={ROLLOUTS}",
        )
        eps = read_episode_metadata(dataset)
        new = eps[eps["adademo/round"] == round_index]
        ledger = [r for r in read_ledger(dataset) if r["round"] == round_index]
        evaluations = {
            (e["task"], e["seed"]): e["success"]
            for e in read_round_evaluations(dataset, round_index)
            if e["type"] == "eval"
        }
        assert sorted(r["task"] for r in ledger) == sorted(TASKS)
        for r in ledger:
            # The plugin's rule: exactly its rollouts, from this round's own states, a demo at every failure.
            seeds = [expansion_state_seed(0, round_index, r["task"], k) for k in range(ROLLOUTS)]
            assert sorted(s for t, s in evaluations if t == r["task"]) == sorted(seeds)
            failed = {s for s in seeds if not evaluations[(r["task"], s)]}
            assert r["strategy"] == "every_failure" and r["eval_episodes"] == ROLLOUTS
            assert r["failures"] == len(failed) == r["demos_added"] + r["expert_failures"]
            task_new = new[new.task == r["task"]]
            assert len(task_new) == r["demos_added"] and set(task_new["adademo/seed"]) <= failed
        assert (new["adademo/source"] == "every_failure").all()
        suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS)))
        for _, ep in new.iterrows():
            np.testing.assert_array_equal(
                ep["adademo/initial_state"], suite.sample_initial_state(ep.task, ep["adademo/seed"])
            )
    assert len(eps) > 6  # the weak policy fails somewhere in two rounds: the plugin did add demonstrations
    assert stock_episodes(dataset) == len(eps)


def test_a_plugin_expert_records_its_own_actions_and_refuses_a_bad_field(tmp_path):
    """`--collector.type=smoothed` from the same package: every recorded action is the moving average of the
    scripted expert's actions along the episode (replayed in the suite's env from the episode's initial state), the
    episodes name it as their expert and stock LeRobot reads them; a weight outside [0, 1) is one `error:` line
    with nothing written."""
    root = tmp_path / "smoothed"
    run_cli(
        "adademo-collect", f"--suite.tasks={','.join(TASKS)}", "--episodes_per_task=2",
        "--collector.type=smoothed", "--collector.smoothing=0.5", "--dataset.repo_id=local/smoothed",
        f"--dataset.root={root}",
    )  # fmt: skip
    eps = read_episode_metadata(root)
    assert list(eps.task) == [TASKS[0]] * 2 + [TASKS[1]] * 2
    assert set(eps["adademo/collector"]) == {"smoothed-metaworld-scripted"}
    suite = make_suite(MetaWorldSuiteConfig(tasks=",".join(TASKS)))
    smoothed_away = 0.0  # how far the largest recorded action is from the scripted expert's own at that step
    for index, ep in eps.iterrows():
        recorded = episode_frames(root, index)["action"]
        env = suite.make_env(ep.task, terminate_on_success=False)
        obs, _ = env.reset(options={"initial_state": ep["adademo/initial_state"]})
        scripted, previous = scripted_policy(ep.task), None
        low, high = env.action_space.low, env.action_space.high
        for action in recorded:
            expert = np.asarray(scripted(obs), np.float64)
            previous = expert if previous is None else 0.5 * previous + 0.5 * expert
            # recorded as the env applied it: clipped to the action space, stored as float32
            np.testing.assert_allclose(action, np.clip(previous, low, high), atol=1e-6)
            smoothed_away = max(smoothed_away, float(np.abs(previous - expert).max()))
            obs, *_ = env.step(previous)
        env.close()
    assert smoothed_away > 0.05  # the smoothing changed what the expert did
    assert stock_episodes(root) == 4

    bad = tmp_path / "bad"
    assert_cli_error(
        "adademo-collect", f"--suite.tasks={TASKS[0]}", "--collector.type=smoothed", "--collector.smoothing=1",
        "--dataset.repo_id=local/bad", f"--dataset.root={bad}",
        match="--collector.smoothing=1.0: give the previous action's weight in [0, 1)",
    )  # fmt: skip
    assert not bad.exists()


def test_a_plugin_that_fails_to_import_is_one_error_line_naming_it(dataset, tmp_path, monkeypatch):
    """An installed distribution named adademo_lerobot_* whose import raises (here on PYTHONPATH, laid out as pip
    installs one: the package and its .dist-info) stops the command before it reads a flag or writes."""
    site = tmp_path / "site"
    (site / "adademo_lerobot_broken").mkdir(parents=True)
    (site / "adademo_lerobot_broken" / "__init__.py").write_text(
        "raise RuntimeError('made for another release')\n"
    )
    info = site / "adademo_lerobot_broken-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: adademo_lerobot_broken\nVersion: 0.1.0\n")
    before = file_digests(dataset)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])))
    line = assert_cli_error(
        "adademo-expand",
        "--dataset.repo_id=local/demo",
        f"--dataset.root={dataset}",
        "--strategy.type=uniform",
        match="the plugin adademo_lerobot_broken failed to import (RuntimeError: made for another release)",
    )
    assert "uninstall it" in line
    assert file_digests(dataset) == before
    monkeypatch.undo()  # without it on the path the same command runs
    expand(dataset, "--strategy.type=uniform", "--strategy.demos_per_task=1")
