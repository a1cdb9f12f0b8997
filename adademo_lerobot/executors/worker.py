"""What runs episodes: one `EpisodeWorker` builds a suite's envs and its expert once, loads each round's policy
once, and then evaluates batches of initial states and collects demonstrations on request.

The local executor calls a worker in the driver's own process; the Ray executor runs one per Ray actor. Both run
the same code on the same units of work (a batch of seeds, or one seed), so results do not depend on where or
in which order they run.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from adademo_lerobot.collectors import CollectorConfig, make_collector
from adademo_lerobot.collectors.takeover import TakeoverArgs
from adademo_lerobot.core.episodes import CollectionResult, EpisodeRecord
from adademo_lerobot.core.threads import set_torch_threads
from adademo_lerobot.suites import make_suite, suite_config_from_dict


class EpisodeWorker:
    def __init__(
        self,
        suite_config: dict,
        collector_config: CollectorConfig,
        eval_batch_size: int,
        device: str,
        torch_threads: int,
    ):
        set_torch_threads(torch_threads)
        self.suite = make_suite(suite_config_from_dict(suite_config))
        self.collector_config = collector_config
        self._collector = None
        self.eval_batch_size, self.device = eval_batch_size, device
        self._policy_path: str | None = None
        self._evaluator = None

    @property
    def collector(self):
        if self._collector is None:  # built on first use: evaluation-only workers never load a policy expert
            self._collector = make_collector(self.collector_config, self.suite)
        return self._collector

    def use_policy(self, path: str | None) -> None:
        """Load the round's policy (once: a worker keeps it until the path changes)."""
        if path == self._policy_path:
            return
        from adademo_lerobot.evaluation.policy import load_policy
        from adademo_lerobot.evaluation.rollouts import BatchedEvaluator

        if self._evaluator is not None:
            self._evaluator.close()
        self._evaluator = (
            BatchedEvaluator(self.suite, load_policy(path, self.device), self.eval_batch_size)
            if path
            else None
        )
        self._policy_path = path

    def evaluate(
        self,
        task: str,
        seeds: list[int],
        policy_path: str,
        takeover: TakeoverArgs | None = None,
        keep_successes: bool = False,
        shard_folder: str | None = None,
    ) -> list[EpisodeRecord]:
        """The policy's episodes from these seeds' initial states; with `takeover`, each failed episode's record
        also says where the expert takes over (chosen here, where the rollout's states are); with
        `keep_successes`, each successful one's record keeps the rollout as data (`kept`: a Demonstration, or
        with `shard_folder` its shard, as `collect` returns them)."""
        self.use_policy(policy_path)  # a restarted worker (after a crash) loads the policy again here
        if takeover is None and not keep_successes:
            return self._evaluator.run(task, seeds)
        from adademo_lerobot.collectors.takeover import choose_takeover
        from adademo_lerobot.dataset.recorder import demonstration_from_trace
        from adademo_lerobot.evaluation.rollouts import one_torch_thread

        records = []
        # The whole states: where a takeover may start, and what a kept success replays from (where they exist).
        with_states = takeover is not None or self.suite.restores_any_state
        for record, trace in self._evaluator.run_traced(task, seeds, with_states):
            if not record.success and takeover is not None:
                with one_torch_thread():
                    point = choose_takeover(trace, takeover, self.collector.expert_first_action(task))
                record.takeover_step, record.takeover_rule = point.step, point.rule
                record.takeover_state = point.state.tolist()
            if record.success and keep_successes:
                record.kept = self._as_result(
                    demonstration_from_trace(task, record.seed, record.initial_state, trace), shard_folder
                )
            records.append(record)
        return records

    def _as_result(self, demo, shard_folder: str | None):
        """A demonstration as a worker hands it back: in memory, or written to its shard in `shard_folder`."""
        if shard_folder is None:
            return demo
        from adademo_lerobot.dataset.shards import write_shard

        return write_shard(Path(shard_folder), self.suite, demo)

    def collect(
        self,
        task: str,
        seed: int,
        start_state: list[float] | None = None,
        takeover: TakeoverArgs | None = None,
        shard_folder: str | None = None,
    ) -> CollectionResult:
        """A demonstration from the seed's initial state, or, for a correction, from `start_state` (`takeover`:
        how many attempts there, and what when they fail). With `shard_folder` the demonstration is written
        there, as a shard (`dataset/shards.py`), and the result carries the shard instead of the frames."""
        from adademo_lerobot.evaluation.rollouts import (
            one_torch_thread,  # a policy expert acts as it would locally
        )

        start = None if start_state is None else np.asarray(start_state, np.float64)
        initial = self.suite.sample_initial_state(task, seed)
        with one_torch_thread():
            result = self.collector.collect(task, initial, seed, start, takeover)
        if result.demonstration is not None:
            result.demonstration = self._as_result(result.demonstration, shard_folder)
        return result

    def collect_many(
        self,
        task: str,
        units: list[tuple[int, list[float] | None]],
        takeover: TakeoverArgs | None = None,
        shard_folder: str | None = None,
    ) -> list[CollectionResult]:
        """`collect` for each (seed, start state) unit, in order: several units in one call (a Ray call costs
        the driver more than a unit's result does)."""
        return [self.collect(task, seed, start, takeover, shard_folder) for seed, start in units]

    def prepare_merge(self, plan) -> dict:
        """Write a planned merge's files (`dataset/shard_merge.py`); returns its episodes' aggregated stats."""
        from adademo_lerobot.dataset.shard_merge import prepare

        return prepare(plan)

    def pid(self) -> int:
        return os.getpid()

    def close(self) -> None:
        if self._evaluator is not None:
            self._evaluator.close()
        if self._collector is not None and hasattr(self._collector, "close"):
            self._collector.close()
