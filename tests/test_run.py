"""adademo-run and adademo-report end to end on the tiny recipe: real collection, training, rollouts."""

import json
import signal
import subprocess
import sys
import time

import pytest
from conftest import BIN, assert_cli_error, run_cli

from adademo_lerobot.collectors import ScriptedCollectorConfig
from adademo_lerobot.core.files import exclusive_use
from adademo_lerobot.core.seeds import evaluation_seeds
from adademo_lerobot.dataset.ledger import read_ledger
from adademo_lerobot.dataset.metadata import read_episode_metadata

STAGES = ["collect", "train-0", "eval-0", "expand-1", "train-1", "eval-1"]
PNG = b"\x89PNG\r\n\x1a\n"


def test_tiny_recipe_end_to_end_with_report(tmp_path):
    run_dir = tmp_path / "adademo"
    proc = run_cli("adademo-run", "--config_path=recipes/tiny.yaml", f"--run_dir={run_dir}")
    assert "run complete" in proc.stdout
    state = json.loads((run_dir / "run_state.json").read_text())
    assert list(state["done"]) == STAGES
    eps = read_episode_metadata(run_dir / "dataset")
    assert (
        set(eps["adademo/round"]) == {0, 1}
        and (eps[eps["adademo/round"] == 1]["adademo/source"] == "adademo").all()
    )
    assert [r["round"] for r in read_ledger(run_dir / "dataset")] == [1, 1]
    for i in (0, 1):  # the fixed evaluation set: same seeds every round, never used for expansion
        import pandas as pd

        records = pd.read_parquet(run_dir / "eval" / f"round-{i:03d}" / "eval_episodes.parquet")
        for task in ("reach-v3", "push-v3"):
            assert list(records[records.task == task].seed) == evaluation_seeds(100, task, 2)
        assert not set(records.seed) & set(eps["adademo/seed"])
    # Round 1 retrains from scratch for steps proportional to the data (the default schedule): 4 x 8 / 4.
    assert len(eps) == 8 and training_step(run_dir, 1) == 8
    report = (run_dir / "report" / "report.md").read_text()
    assert "round 0: SR % (demos)" in report and "round 1: SR % (demos)" in report and "reach-v3" in report
    assert "| 1 | adademo |" in report  # the ledger's round
    assert "Expert (`collector` in the ledger): round 1: scripted." in report  # at its defaults
    assert state["settings"]["collector"] == ScriptedCollectorConfig().to_dict()
    # Can its demonstrations be imitated? 4 a task are too few to score, and the report says so per task.
    assert "Can a policy imitate these demonstrations?" in report
    assert "| reach-v3 | 4 | - | too few demonstrations" in report and "| push-v3 | 4 | - | too few" in report
    for png in ("success_vs_demos.png", "eval_cost.png", "allocation_adademo.png", "success_adademo.png"):
        assert (run_dir / "report" / png).read_bytes()[:8] == PNG

    # A second arm and a comparison report.
    uniform = tmp_path / "uniform"  # ... fine-tuning from the previous round, as every shipped recipe does
    run_cli(
        "adademo-run",
        "--config_path=recipes/tiny.yaml",
        f"--run_dir={uniform}",
        "--strategy.type=uniform",
        "--train.sampler=task",
        "--train.mode=finetune",
        "--train.finetune_steps=3",
    )
    assert training_step(uniform, 1) == 3
    round_1 = json.loads(
        (uniform / "train/round-1/checkpoints/last/pretrained_model/train_config.json").read_text()
    )
    assert round_1["policy"]["pretrained_path"] == str(
        (uniform / "train/round-0/checkpoints/last/pretrained_model").resolve()
    )
    out = tmp_path / "compare"
    run_cli("adademo-report", f"--run_dir={run_dir}", "--compare", str(uniform), f"--output_dir={out}")
    compared = (out / "report.md").read_text()
    assert (
        "| adademo | adademo + trajectory sampler |" in compared
        and "| uniform | uniform + task sampler |" in compared
    )
    # Without --compare_to: one line on how to get the break-even cost.
    assert "add `--compare_to=<a Uniform run on the same tasks>`" in compared

    # The break-even rollout cost against the Uniform run, from both runs' ledgers.
    proc = run_cli("adademo-report", f"--run_dir={run_dir}", f"--compare_to={uniform}", f"--output_dir={out}")
    assert_break_even(proc.stdout, run_dir, uniform)
    assert_break_even((out / "report.md").read_text(), run_dir, uniform)
    assert_cli_error(
        "adademo-report",
        f"--run_dir={run_dir}",
        f"--compare_to={tmp_path}",
        match="not an adademo-run folder",
    )
    other = tmp_path / "other_tasks"  # a run on other tasks (its state says so; refused before its results)
    other.mkdir()
    state = json.loads((uniform / "run_state.json").read_text())
    state["settings"]["suite"]["tasks"] = "reach-v3"
    (other / "run_state.json").write_text(json.dumps(state))
    assert_cli_error(
        "adademo-report", f"--run_dir={run_dir}", f"--compare_to={other}", match="ran other tasks"
    )
    assert_cli_error(  # a run that ran rollouts is no Uniform run: c* is defined against one that runs none
        "adademo-report", f"--run_dir={uniform}", f"--compare_to={run_dir}", match="ran 4 policy rollouts"
    )


def assert_break_even(text: str, run_dir, uniform) -> None:
    """The plain-words c*, recomputed here from the ledgers (every failed attempt runs the 300-step limit)."""

    def expert_episodes(rows) -> int:
        return sum(r["demos_added"] + (r["collection_env_steps"] - r["demo_frames"]) // 300 for r in rows)

    def average(run, r: int) -> float:
        summary = json.loads((run / "eval" / f"round-{r:03d}" / "eval_summary.json").read_text())
        return next(row["success_rate"] for row in summary["per_task"] if row["task"] == "average")

    mine, theirs = read_ledger(run_dir / "dataset"), read_ledger(uniform / "dataset")
    target = average(uniform, 1)
    used = f"Uniform used {expert_episodes(theirs)} expert episodes"
    reached = [r for r in (0, 1) if average(run_dir, r) >= target]
    assert "| after round | demonstrations | expert frames | expert episodes | rollouts | episodes |" in text
    if not reached:
        assert f"This run never reached the Uniform run's final {100 * target:.1f} %" in text and used in text
        return
    if reached[0] == 0:  # the Uniform run ended no higher than where both started: nothing to break even on
        assert (
            f"The Uniform run's final {100 * target:.1f} % is no higher than where this run started "
            f"({100 * average(run_dir, 0):.1f} % at round 0): it is reached with nothing added" in text
        )
        return
    spent = [r for r in mine if r["round"] <= reached[0]]
    x, n = expert_episodes(spent), sum(r["eval_episodes_run"] for r in spent)
    c = (expert_episodes(theirs) - x) / n if n else None
    words = (
        "pays off whatever a policy rollout costs"
        if c is None
        else "does not pay off even with free rollouts"
        if c < 0
        else f"pays off if a policy rollout costs less than {c:.2f} of an expert episode"
    )
    assert (
        f"On this run AdaDemo {words} (it reached the Uniform run's final {100 * target:.1f} % with round "
        f"{reached[0]}'s policy, after {x} expert episodes and {n} rollouts; {used})."
    ) in text


def training_step(run_dir, i: int) -> int:
    path = run_dir / "train" / f"round-{i}" / "checkpoints" / "last" / "training_state" / "training_step.json"
    return json.loads(path.read_text())["step"]


# adademo-run's own entry point, run with a hook that kills the process right after round 1's ledger write.
KILLED_AFTER_THE_LEDGER = """
import os

import adademo_lerobot.commands  # noqa: F401  (the process settings of a command)
from adademo_lerobot.loop.cli import run_command
from adademo_lerobot.loop.run import RunConfig, run

run_command(lambda cfg: run(cfg, on_ledger_written=lambda r: os.kill(os.getpid(), 9)), RunConfig)
"""


@pytest.mark.slow
def test_a_kill_between_the_ledger_and_the_journal_end_loses_no_round(tmp_path):
    """The round number is one truth: a kill right after round 1's ledger write, before its journal is closed,
    must not make the rerun skip round 2 (it used to record round 2 as done with no demos)."""
    run_dir = tmp_path / "run"
    args = ["--config_path=recipes/tiny.yaml", f"--run_dir={run_dir}", "--rounds=2"]
    proc = subprocess.run(
        [sys.executable, "-c", KILLED_AFTER_THE_LEDGER, *args], capture_output=True, text=True, timeout=900
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    dataset = run_dir / "dataset"
    assert [r["round"] for r in read_ledger(dataset)] == [1, 1]
    assert (dataset / "meta" / "adademo" / "journal-round-001.jsonl").exists()  # the kill came before its end
    run_cli("adademo-run", *args)
    state = json.loads((run_dir / "run_state.json").read_text())["done"]
    assert state["expand-1"]["result"]["demos_added"] == {"reach-v3": 2, "push-v3": 2}
    assert state["expand-2"]["result"]["demos_added"] == {
        "reach-v3": 2,
        "push-v3": 2,
    }  # round 2 was collected
    assert [r["round"] for r in read_ledger(dataset)] == [1, 1, 2, 2]
    eps = read_episode_metadata(dataset)
    assert sorted(eps["adademo/round"].value_counts().items()) == [(0, 4), (1, 4), (2, 4)]
    assert not list((dataset / "meta" / "adademo").glob("journal-round-*.jsonl"))


@pytest.mark.slow
def test_kill_midway_then_rerun_finishes_without_redoing_stages(tmp_path):
    run_dir = tmp_path / "killed"
    args = [
        "--config_path=recipes/tiny.yaml",
        f"--run_dir={run_dir}",
        "--train.steps=40",
        "--train.save_freq=10",
    ]
    proc = subprocess.Popen(
        [str(BIN / "adademo-run"), *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    state_path = run_dir / "run_state.json"
    deadline = time.time() + 600
    while True:
        assert time.time() < deadline and proc.poll() is None, "the run ended before it could be killed"
        if state_path.exists() and "eval-0" in json.loads(state_path.read_text())["done"]:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = json.loads(state_path.read_text())["done"]
    rerun = run_cli("adademo-run", *args)
    for stage in before:
        assert f"[done] {stage}" in rerun.stdout
    after = json.loads(state_path.read_text())["done"]
    assert list(after) == STAGES
    assert all(after[s] == before[s] for s in before)  # finished stages were not redone
    assert (run_dir / "report" / "report.md").exists()


@pytest.mark.slow
def test_run_bad_input(tmp_path):
    assert_cli_error("adademo-run", "--config_path=recipes/tiny.yaml", match="--run_dir")
    assert_cli_error(
        "adademo-run",
        "--config_path=recipes/tiny.yaml",
        f"--run_dir={tmp_path / 'r'}",
        "--strategy.type=random",
        match="strategy",
    )
    assert_cli_error(
        "adademo-run",
        "--config_path=recipes/tiny.yaml",
        f"--run_dir={tmp_path / 'r'}",
        "--strategy.target_successes=[0]",
        match="target_successes",
    )
    assert_cli_error("adademo-report", f"--run_dir={tmp_path}", match="run_state.json")
    assert not (tmp_path / "r").exists()
    busy = tmp_path / "busy"  # another adademo-run works in this folder: refused before anything is written
    busy.mkdir()
    with exclusive_use(busy, "a test"):
        assert_cli_error(
            "adademo-run",
            "--config_path=recipes/tiny.yaml",
            f"--run_dir={busy}",
            match="in use by another running adademo command",
        )
    assert list(busy.iterdir()) == []


def test_a_changed_learning_rate_schedule_is_refused_on_resume_but_an_older_run_resumes(tmp_path):
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.loop.run_state import RunState

    RunState(tmp_path, {"strategy": "adademo", "lr_schedule": "preset"})
    with pytest.raises(AdaDemoError, match="lr_schedule: 'preset' -> 'cosine'"):
        RunState(tmp_path, {"strategy": "adademo", "lr_schedule": "cosine"})
    older = tmp_path / "older"  # started before lr_schedule was recorded: it used the policy's preset
    older.mkdir()
    (older / "run_state.json").write_text(
        json.dumps({"settings": {"strategy": "adademo"}, "done": {"collect": {}}})
    )
    now = {"strategy": "adademo", "lr_schedule": "preset", "demo_start": "initial", "takeover": None}
    assert RunState(older, now).done == {"collect": {}}
    with pytest.raises(AdaDemoError, match="lr_schedule"):
        RunState(older, {"strategy": "adademo", "lr_schedule": "cosine"})


# Every field of the config settings a run journals, so far. A field added from now on: its default must keep the
# behaviour from before it (a run journaled before the field resumes as that default), or it goes into
# run_state.FIELDS_WITHOUT_A_PAST_DEFAULT (such a run is refused); then add it here.
KNOWN_FIELDS = {
    "takeover": {"attempts", "backoff", "consecutive", "fallback", "rule", "stall_tolerance", "threshold"},
    "strategy": {
        "budget", "limit_disagreeing", "max_demos_per_task", "max_eval_episodes_per_task", "posterior_decay",
        "target_successes", "failure_worth", "optimism", "probe_unsure", "rank_states", "rollout_cost",
        "split_episodes", "plan_episodes_per_task", "demos_per_task",
    },
    "suite": {"camera", "image_size", "max_episode_steps", "obs_type", "tasks", "env"},
    "collector": {
        "max_attempts", "post_success_frames", "retry_action_noise", "entry", "path", "samples", "horizon",
        "knot_steps", "iterations", "noise", "temperature", "common_noise", "plan_decay", "reward",
        "scripted_tasks", "scripted_first", "task_settings",
    },
}  # fmt: skip


def test_a_run_started_before_a_config_field_existed_resumes_as_that_field_s_default(tmp_path):
    from adademo_lerobot.collectors import CollectorConfig
    from adademo_lerobot.collectors.takeover import TakeoverArgs
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.loop.run_state import FIELDS_WITHOUT_A_PAST_DEFAULT, RunState
    from adademo_lerobot.strategies import StrategyConfig
    from adademo_lerobot.strategies.adademo import AdaDemoConfig
    from adademo_lerobot.suites import SuiteConfig

    later = {"lr_schedule": "cosine", "demo_start": "takeover"}

    def journal(run_dir, settings: dict):
        run_dir.mkdir(exist_ok=True)
        state = {"settings": {**later, **settings}, "done": {"collect": {}}}
        (run_dir / "run_state.json").write_text(json.dumps(state))
        return run_dir

    configs = [("takeover", TakeoverArgs)]  # every field of every config setting, today's and a new one's
    registries = {"strategy": StrategyConfig, "suite": SuiteConfig, "collector": CollectorConfig}
    for setting, registry in registries.items():
        configs += [(setting, registry.get_choice_class(n)) for n in registry.get_known_choices()]
    # Ours: an installed plugin's types (examples/adademo_lerobot_example) keep their own fields' history.
    configs = [(s, c) for s, c in configs if c.__module__.startswith("adademo_lerobot.")]
    for setting, config in configs:
        defaults = config().to_dict()
        assert set(defaults) - {"type"} <= KNOWN_FIELDS[setting], "a new field: see KNOWN_FIELDS"
        for field in set(defaults) - {"type"}:
            without = {k: v for k, v in defaults.items() if k != field}
            older = journal(tmp_path / f"{setting}-{config.__name__}-{field}", {setting: without})
            now = {setting: defaults, **later}
            if field in FIELDS_WITHOUT_A_PAST_DEFAULT.get(setting, ()):  # older runs did otherwise
                with pytest.raises(AdaDemoError, match=setting):
                    RunState(older, now)
                continue
            assert RunState(older, now).done == {"collect": {}}, (setting, config, field)
            assert json.loads((older / "run_state.json").read_text())["settings"][setting] == defaults

    # An adademo run started before --strategy.limit_disagreeing ran without the limit: turning it on is refused.
    journaled = AdaDemoConfig(budget=[40, 60]).to_dict()
    del journaled["limit_disagreeing"]
    now = {"strategy": AdaDemoConfig(budget=[40, 60]).to_dict(), **later}
    assert RunState(journal(tmp_path / "off", {"strategy": journaled}), now).done
    limited = {"strategy": AdaDemoConfig(budget=[40, 60], limit_disagreeing=True).to_dict(), **later}
    with pytest.raises(AdaDemoError, match="strategy.limit_disagreeing: False -> True"):
        RunState(journal(tmp_path / "on", {"strategy": journaled}), limited)
    changed = {"strategy": AdaDemoConfig(budget=[40, 80]).to_dict(), **later}
    # Nor does a field missing let another one change; the refusal names the field, not the whole strategy.
    with pytest.raises(AdaDemoError, match=r"\(strategy.budget: \[40, 60\] -> \[40, 80\]\);"):
        RunState(journal(tmp_path / "budget", {"strategy": journaled}), changed)


def test_training_seed_batch_size_autonomous_weight_and_expert_are_fixed_once_recorded(tmp_path):
    from adademo_lerobot.collectors import PlannerCollectorConfig, ScriptedCollectorConfig
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.loop.run_state import RunState

    older = {"strategy": "adademo", "lr_schedule": "preset"}  # a run that did not record them: not checked
    (tmp_path / "run_state.json").write_text(json.dumps({"settings": older, "done": {"collect": {}}}))
    now = {**older, "demo_start": "initial", "takeover": None, "train_seed": 1000, "batch_size": 32}
    now |= {"autonomous_weight": 0.0, "collector": PlannerCollectorConfig(samples=8).to_dict()}
    assert RunState(tmp_path, now).done == {"collect": {}}
    for changed in (
        {"train_seed": 1001},
        {"batch_size": 64},
        {"autonomous_weight": 0.5},
        {"collector": PlannerCollectorConfig(samples=16).to_dict()},
        {"collector": ScriptedCollectorConfig().to_dict()},
    ):  # recorded now
        with pytest.raises(AdaDemoError, match=next(iter(changed))):
            RunState(tmp_path, {**now, **changed})
    # The planner's threads set its speed only: a resumed run may use more.
    faster = {**now, "collector": PlannerCollectorConfig(samples=8, threads=2).to_dict()}
    assert RunState(tmp_path, faster).done == {"collect": {}}


def test_a_run_started_before_the_strategy_registry_resumes_with_its_strategy_type_checked(tmp_path):
    from adademo_lerobot.core.errors import AdaDemoError
    from adademo_lerobot.loop.run_state import RunState

    (tmp_path / "run_state.json").write_text(  # 0.2: the strategy was a name, its values top-level flags
        json.dumps({"settings": {"strategy": "uniform", "budget": [32, 48]}, "done": {"collect": {}}})
    )
    later = {"lr_schedule": "preset", "demo_start": "initial", "takeover": None}  # recorded after 0.2
    now = {"strategy": {"type": "uniform", "demos_per_task": [10, 20], "budget": [32, 48]}, **later}
    assert RunState(tmp_path, now).done == {"collect": {}}
    assert json.loads((tmp_path / "run_state.json").read_text())["settings"]["strategy"] == now["strategy"]
    assert RunState(tmp_path, now).done == {"collect": {}}  # and again, from the settings it now records
    (tmp_path / "run_state.json").write_text(
        json.dumps({"settings": {"strategy": "uniform"}, "done": {"collect": {}}})
    )
    with pytest.raises(AdaDemoError, match="strategy"):
        RunState(tmp_path, {"strategy": {"type": "budgeted", "budget": [32, 48]}, **later})


def test_a_resumed_stage_reports_the_seconds_of_every_invocation_that_worked_on_it(tmp_path):
    from adademo_lerobot.loop.run_state import RunState

    settings = {
        "strategy": {"type": "uniform"},
        "lr_schedule": "preset",
        "demo_start": "initial",
        "takeover": None,
    }

    def interrupted():
        time.sleep(0.3)
        raise KeyboardInterrupt

    heard = []  # what adademo-run prints of its stages
    with pytest.raises(KeyboardInterrupt):
        RunState(tmp_path, settings, on_stage=heard.append).stage("train_0", interrupted)
    resumed = RunState(tmp_path, settings, on_stage=heard.append)  # the next invocation of the same command
    assert resumed.stage("train_0", lambda: time.sleep(0.2) or "checkpoint") == "checkpoint"
    state = json.loads((tmp_path / "run_state.json").read_text())
    assert state["done"]["train_0"]["seconds"] >= 0.45  # 0.3 s interrupted + 0.2 s resumed, not 0.2 s
    assert "interrupted" not in state  # counted once: a later stage starts from zero
    assert RunState(tmp_path, settings, on_stage=heard.append).stage("train_0", interrupted) == "checkpoint"
    assert heard == ["[run]  train_0", "[run]  train_0", "[done] train_0"]
    assert json.loads((tmp_path / "run_state.json").read_text()) == state  # a finished stage is not rerun


def test_the_report_names_each_round_s_expert_by_the_settings_it_changed():
    import pandas as pd

    from adademo_lerobot.collectors import PlannerCollectorConfig
    from adademo_lerobot.collectors.planner import PlannerTaskSettings
    from adademo_lerobot.loop.report import expert_lines

    hammer = {"hammer": PlannerTaskSettings(common_noise=True)}
    planner = PlannerCollectorConfig(samples=16, threads=2, task_settings=hammer).to_dict()
    person = {"type": "person", "teleop": "so101_leader", "robot": "so101_follower"}
    rounds = [
        (1, {}),
        (2, planner),
        (2, planner),
        (3, planner),
        (4, person),
        (5, planner),
    ]  # round 1 before 0.4
    ledger = pd.DataFrame([{"round": r, "task": "hammer", "collector": c} for r, c in rounds])
    planned = "planner (samples=16, task_settings={'hammer': {'common_noise': True}})"
    assert expert_lines(ledger) == [
        "",
        f"Expert (`collector` in the ledger): rounds 2-3: {planned}; "
        "round 4: person (teleop=so101_leader, robot=so101_follower); "
        f"round 5: {planned}.",
    ]
    assert expert_lines(ledger.drop(columns="collector")) == []  # a ledger written before it was recorded
