"""The two parses of a command: the first (no LeRobot import) reads LeRobot's choice fields as dicts, the full one
as LeRobot's configs, from the same flags and recipe."""

from pathlib import Path

import pytest
from conftest import run_cli
from lerobot.configs.policies import PreTrainedConfig

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.loop.cli import parse_config, parse_light
from adademo_lerobot.loop.configs import ExpandConfig, RecordConfig, TrainCommandFlags
from adademo_lerobot.loop.run import RunConfig
from adademo_lerobot.loop.train import AdaDemoTrainConfig

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "quickstart.yaml"


def test_run_recipe_policy_is_a_dict_first_and_lerobots_config_in_full():
    argv = [f"--config_path={RECIPE}", "--run_dir=/tmp/r", "--train.policy.dim_model=32", "--rounds=3"]
    light = parse_light(RunConfig, argv)
    assert light.train.policy["type"] == "act" and light.train.policy["dim_model"] == "32"  # flag over recipe
    assert light.train.policy["n_heads"] == 4  # the recipe's own field kept beside the flag
    full = parse_config(RunConfig, argv)
    assert isinstance(full.train.policy, PreTrainedConfig) and full.train.policy.type == "act"
    assert (full.train.policy.dim_model, full.train.policy.n_heads) == (32, 4)
    assert (full.rounds, light.rounds) == (3, 3) and full.suite == light.suite
    assert isinstance(full, RunConfig)  # the full config is the light one with LeRobot's types in place
    full.validate()


def test_record_devices_are_lerobots_configs_in_full():
    argv = [
        "--robot.type=adademo_sim",
        "--robot.task=reach-v3",
        "--teleop.type=adademo_scripted",
        "--policy.path=/p",
        "--dataset.root=/d",
    ]
    light = parse_light(RecordConfig, argv)
    assert light.robot == {"type": "adademo_sim", "task": "reach-v3"} and light.teleop == {
        "type": "adademo_scripted"
    }
    full = parse_config(RecordConfig, argv)
    assert (full.robot.type, full.teleop.type) == ("adademo_sim", "adademo_scripted")
    assert full.robot.task == "reach-v3"


def test_train_own_flags_parse_first_and_lerobot_flags_in_full():
    argv = [
        "--policy.type=act",
        "--dataset.repo_id=x/y",
        "--steps=7",
        "--sampler=tempered",
        "--sampler_alpha=0.5",
    ]
    light = parse_light(TrainCommandFlags, argv, known_only=True)
    assert (light.sampler, light.sampler_alpha) == ("tempered", 0.5)
    full = parse_config(AdaDemoTrainConfig, argv)
    assert (full.sampler, full.sampler_alpha, full.steps, full.policy.type) == ("tempered", 0.5, 7, "act")
    assert full.batch_size == 64  # our default over lerobot-train's


def test_cosine_lr_schedule_decays_to_one_percent_of_the_policys_rate(tmp_path):
    argv = [
        "--policy.type=act",
        "--policy.optimizer_lr=0.0003",
        "--dataset.repo_id=x/y",
        f"--dataset.root={tmp_path}",
    ]
    preset = parse_config(AdaDemoTrainConfig, [*argv, f"--output_dir={tmp_path / 'a'}", "--steps=500"])
    preset.validate()
    assert preset.scheduler is None  # ACT's own schedule: a constant rate
    cosine = parse_config(
        AdaDemoTrainConfig, [*argv, f"--output_dir={tmp_path / 'b'}", "--steps=500", "--lr_schedule=cosine"]
    )
    cosine.validate()
    assert cosine.scheduler.type == "cosine_decay_with_warmup"
    assert cosine.scheduler.peak_lr == 3e-4 and cosine.scheduler.decay_lr == pytest.approx(3e-6)
    assert (cosine.scheduler.num_warmup_steps, cosine.scheduler.num_decay_steps) == (10, 500)


def test_a_save_frequency_under_one_is_refused_before_training(tmp_path):
    argv = ["--policy.type=act", "--dataset.repo_id=x/y", f"--dataset.root={tmp_path}", "--steps=5"]
    for freq in (0, -3):
        cfg = parse_config(
            AdaDemoTrainConfig, [*argv, f"--output_dir={tmp_path / str(freq)}", f"--save_freq={freq}"]
        )
        with pytest.raises(AdaDemoError, match=f"--save_freq must be >= 1 .*got {freq}"):
            cfg.validate()
    parse_config(AdaDemoTrainConfig, [*argv, f"--output_dir={tmp_path / 'one'}", "--save_freq=1"]).validate()


@pytest.mark.parametrize(
    "recipe",
    sorted(p.name for p in RECIPE.parent.glob("*.yaml") if p.name != "continue_from_checkpoint.yaml"),
)
def test_every_recipe_parses_in_full_and_validates(recipe):
    argv = [f"--config_path={RECIPE.parent / recipe}", "--run_dir=/tmp/r"]
    parse_light(RunConfig, argv).validate()
    full = parse_config(RunConfig, argv)
    full.validate()
    per_round = [v for v in vars(full.strategy).values() if isinstance(v, tuple) and v]
    assert per_round and all(len(v) == full.rounds for v in per_round)  # E, CAP or B: one per round


def test_the_continue_recipe_asks_for_the_users_checkpoint():
    argv = [f"--config_path={RECIPE.parent / 'continue_from_checkpoint.yaml'}", "--run_dir=/tmp/r"]
    with pytest.raises(AdaDemoError, match="--policy.path"):
        parse_light(RunConfig, argv).validate()


def test_run_hands_its_round_flags_to_each_expansion_as_adademo_expand_reads_them(tmp_path):
    argv = [
        "--strategy.type=budgeted",
        "--strategy.budget=[7,9]",
        "--demo_start=takeover",
        "--commit_every=3",
        "--torch_threads=1",
        "--executor=ray",
        "--ray.num_workers=3",
        "--seed=5",
        "--eval.batch_size=4",
    ]
    run_cfg = parse_light(RunConfig, ["--run_dir=/tmp/r", *argv])
    expand_cfg = run_cfg.expand_config(tmp_path / "ds", "local/ds", tmp_path / "ckpt")
    expected = parse_light(
        ExpandConfig,
        [
            *argv,
            f"--dataset.root={tmp_path / 'ds'}",
            "--dataset.repo_id=local/ds",
            f"--policy.path={tmp_path / 'ckpt'}",
        ],
    )
    assert expand_cfg == expected
    assert expand_cfg.strategy.budget.at(2) == 9 and expand_cfg.ray.num_workers == 3


@pytest.mark.parametrize(
    ("strategy", "plans"),
    [
        (["--strategy.type=adademo"], True),
        (["--strategy.type=adademo", "--strategy.budget=20"], True),  # E is picked from the budget first
        (["--strategy.type=task_only"], True),
        (["--strategy.type=task_only", "--strategy.budget=20"], False),  # the budgeted loop: no N_k rule
        (["--strategy.type=budgeted", "--strategy.budget=20"], False),
        (["--strategy.type=uniform", "--strategy.demos_per_task=2"], False),
    ],
)
def test_plan_only_is_refused_for_a_strategy_that_cannot_plan(strategy, plans):
    cfg = parse_light(ExpandConfig, ["--dataset.root=/d", "--policy.path=/p", "--plan_only=true", *strategy])
    assert cfg.strategy.can_plan() is plans
    if plans:
        cfg.validate()
    else:
        with pytest.raises(AdaDemoError, match="--plan_only predicts N_k = E/SR_k - E: it needs"):
            cfg.validate()


def test_an_import_that_fails_mid_command_is_one_error_line_that_says_it_resumes(monkeypatch, capsys):
    """A module first imported late in a long command (the report at a run's end) after the package changed on disk,
    or a missing one: one `error:` line, exit 1, not a traceback."""
    from adademo_lerobot.loop.cli import run_command
    from adademo_lerobot.loop.configs import ReportConfig

    monkeypatch.setattr("sys.argv", ["adademo-report"])
    with pytest.raises(SystemExit) as exit_info:
        run_command("adademo_lerobot.loop.no_such_module:write_report", ReportConfig)
    assert exit_info.value.code == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "error: No module named 'adademo_lerobot.loop.no_such_module'"
    )
    assert "run the same command to resume" in lines[0]


def test_a_command_after_a_stopped_one_in_the_same_process_still_stops(monkeypatch, capsys):
    """A stopped command ignores further signals while it unwinds; the next command run in the same process (a
    library caller, a notebook) is not stopping: its SIGTERM (or Ctrl-C) stops it too."""
    import os
    import signal
    import time

    from adademo_lerobot.loop.cli import run_command
    from adademo_lerobot.loop.configs import ReportConfig

    finished = []

    def terminated_then_working(cfg):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)  # the handler raises here
        finished.append(cfg)

    monkeypatch.setattr("sys.argv", ["adademo-report"])
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        for _ in range(2):
            with pytest.raises(SystemExit) as exit_info:
                run_command(terminated_then_working, ReportConfig)
            assert exit_info.value.code == 130
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert finished == []
    assert capsys.readouterr().err.count("interrupted: rerun the same command to resume") == 2


@pytest.mark.parametrize(
    "command, args, message",
    [
        ("adademo-train", ["--dataset.root=ROOT/ds"], "error: --dataset.repo_id is required"),
        (
            "adademo-run",
            ["--config_path=ROOT/no_such.yaml", "--run_dir=ROOT/run"],
            "error: --config_path=ROOT/no_such.yaml: no such file; give a recipe's YAML file",
        ),
        (
            "adademo-run",
            ["--config_path=ROOT", "--run_dir=ROOT/run"],
            "error: --config_path=ROOT: a folder; give a recipe's YAML file",
        ),
    ],
)
def test_a_missing_setting_or_recipe_is_named_as_the_flag_to_give(command, args, message, tmp_path):
    """Not draccus' "`dataset`: Missing required field(s) `repo_id` for DatasetConfig" or an OS error: the flag."""
    proc = run_cli(command, *(a.replace("ROOT", str(tmp_path)) for a in args), check=False)
    lines = proc.stderr.strip().splitlines()
    assert (
        proc.returncode == 2
        and len(lines) == 1
        and lines[0].startswith(message.replace("ROOT", str(tmp_path)))
    )
    assert sorted(tmp_path.iterdir()) == []  # nothing written
