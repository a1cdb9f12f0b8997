"""The loop on a third-party LeRobot env (lerobot-env-so101) against the env's own stepping, in one run.

    python benchmarks/lerobot_env_speed.py [--episodes 30] [--demos 20]

The `lerobot_env` suite adds our wrapper around the plugin's env (seeded restores, the task one-hot, success from
the step's info), the evaluator (a small ACT, batches of 10) and the expert's recording. "Raw" is the plugin's own
`env.step` of the very same episodes, timed inside the loop, so loop / raw is the share of the loop's time the
simulator gets. For reference, the stock env stepped alone with random actions is timed too. One process, one
thread. Writes benchmarks/results/lerobot_env_speed.md.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from _common import BIN, RESULTS, StepClock, loop_speed_args, machine_line, sh, train_small_act

TASK = "SO101PickPlace-v0"
SUITE = ["--suite.type=lerobot_env", "--suite.env.type=so101", "--suite.env.random_block_position=true"]
EXPERT = "adademo_lerobot.collectors.so101:pick_place"


def stock_rate(steps: int = 3000) -> float:
    import gymnasium as gym
    import lerobot_env_so101  # noqa: F401

    env = gym.make(f"lerobot_env_so101/{TASK}", image_obs=False, random_block_position=True, action_scale=1.0,
                   max_episode_steps=100, disable_env_checker=True)  # fmt: skip
    env.reset(seed=0)
    start, done = time.perf_counter(), 0
    for k in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done += 1
        if terminated or truncated:
            env.reset(seed=k)
    return done / (time.perf_counter() - start)


def main() -> None:
    args = loop_speed_args(30, "evaluation episodes", "expert episodes")
    from adademo_lerobot.collectors import CallableCollectorConfig
    from adademo_lerobot.executors import LocalExecutor
    from adademo_lerobot.loop.evaluate import evaluate_fixed_set
    from adademo_lerobot.suites import LeRobotEnvSuiteConfig, make_suite

    suite = make_suite(
        LeRobotEnvSuiteConfig(tasks=TASK, env={"type": "so101", "random_block_position": True})
    )
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sh(BIN / "adademo-collect", *SUITE, f"--suite.tasks={TASK}", "--collector.type=callable",
           f"--collector.entry={EXPERT}", "--episodes_per_task=4", "--dataset.repo_id=local/bench",
           f"--dataset.root={tmp / 'ds'}")  # fmt: skip
        ckpt = str(train_small_act(tmp / "ds", tmp / "train", steps=20))
        from adademo_lerobot.suites.lerobot_env import LeRobotEnvTaskEnv

        clock = StepClock(LeRobotEnvTaskEnv)  # the plugin's own env.step
        local = LocalExecutor(suite, CallableCollectorConfig(entry=EXPERT), batch_size=10, device="cpu",
                              torch_threads=1)  # fmt: skip
        local.use_policy(ckpt)
        evaluate_fixed_set(suite, local, 99, 2)  # warm-up: first inference and env construction
        clock.reset()
        start = time.perf_counter()
        _, eval_steps, _ = evaluate_fixed_set(suite, local, 1, args.episodes)
        eval_seconds, eval_raw = time.perf_counter() - start, clock.steps / clock.seconds
        clock.reset()
        start = time.perf_counter()
        results = [local.collect(TASK, 1000 + k).result() for k in range(args.demos)]
        collect_seconds, collect_raw = time.perf_counter() - start, clock.steps / clock.seconds
        collect_steps = sum(r.env_steps for r in results)
        local.close()
    alone = stock_rate()
    eval_rate, collect_rate = eval_steps / eval_seconds, collect_steps / collect_seconds
    lines = [
        "# The loop on a third-party LeRobot env: lerobot-env-so101 against its own stepping",
        "",
        f"Command: `python benchmarks/lerobot_env_speed.py --episodes {args.episodes} --demos {args.demos}`; "
        f"{machine_line()}.",
        f"Suite `lerobot_env`, env type `so101`, task {TASK} (random layouts, state observations, 100-step limit), "
        "one process, one torch thread. Evaluation: a small ACT (`policies/act_state_cpu.yaml`, 20 training steps), "
        f"{args.episodes} episodes in batches of 10. Collection: {args.demos} episodes of the package's own "
        "pick-and-place controller (`--collector.type=callable`), recorded, not written. Raw: the plugin's own "
        "`env.step` of the same episodes, timed inside the loop.",
        "",
        "| loop | steps/s | raw steps/s (same episodes) | loop / raw |",
        "| --- | --- | --- | --- |",
        f"| evaluation | {eval_rate:.0f} | {eval_raw:.0f} | **{eval_rate / eval_raw:.2f}** |",
        f"| collection | {collect_rate:.0f} | {collect_raw:.0f} | **{collect_rate / collect_raw:.2f}** |",
        "",
        f"The stock env alone, random actions, its own resets: {alone:.0f} steps/s (goal: the loop at >= 0.8x of "
        "the env's raw stepping).",
    ]
    (RESULTS / "lerobot_env_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
