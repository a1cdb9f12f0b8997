"""A trained policy as the expert (`--collector.type=policy --collector.path=...`), for any suite.

Two kinds of `path`:

- a LeRobot checkpoint folder (`.../pretrained_model` with `config.json` and `model.safetensors`), loaded with
  its pre/post-processors and checked against the suite's features (`adademo_lerobot.evaluation.policy`); it acts exactly as in `adademo-eval` (batch of one,
  the task description as `task`, `policy.reset()` at the start of every attempt, action chunks as the policy
  queues them);
- a TorchScript file (`torch.jit.save`): a module mapping the `environment_state` vector, a float32 tensor of
  shape (1, env_state_dim), to the action, shape (1, action_dim) or (action_dim,) (e.g. an RL policy exported
  from DAPG/mjrl weights for Adroit). It must be deterministic; it is called once per step.

Like every collector, an attempt counts only if the suite reports success; failed initial states are retried
with seeded action noise (`--collector.max_attempts`) and otherwise skipped and reported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from adademo_lerobot.collectors.base import CollectorConfig, ExpertCollector, SimulatedExpertCollector
from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.evaluation.policy import load_checked_policy
from adademo_lerobot.suites.base import TaskSuite


@CollectorConfig.register_subclass("policy")
@dataclass
class PolicyCollectorConfig(CollectorConfig):
    """A LeRobot checkpoint folder or a TorchScript file used as the expert."""

    path: str | None = None
    device: str = "cpu"
    execution_fields: ClassVar[tuple[str, ...]] = ("device",)
    # For the messages that list the experts a suite can use.
    expert_hint: ClassVar[str] = "a trained policy as the expert, --collector.path=CHECKPOINT"

    def build(self, suite: TaskSuite) -> ExpertCollector:
        return CheckpointExpert(suite, self)

    def expert_name(self, suite: TaskSuite) -> str:
        return CheckpointExpert.name

    def expert_class(self, suite: TaskSuite) -> type:
        return CheckpointExpert


class CheckpointExpert(SimulatedExpertCollector):
    name = "policy"

    def __init__(self, suite: TaskSuite, config: PolicyCollectorConfig):
        super().__init__(suite, config)
        path = config.path
        if not path:
            raise AdaDemoError(
                "--collector.path is required for --collector.type=policy (a LeRobot checkpoint "
                "folder or a TorchScript file)"
            )
        path = Path(path)
        if not path.exists():
            raise AdaDemoError(f"--collector.path={path} does not exist")
        self.path = path
        self.device = config.device
        if path.is_dir():
            self._loaded = load_checked_policy(path, dataset_features(suite), self.device)
            self._module = None
        else:
            import torch

            try:
                self._module = torch.jit.load(str(path), map_location=self.device).eval()
            except Exception as exc:  # noqa: BLE001  (torch raises RuntimeError/ValueError for non-TorchScript)
                raise AdaDemoError(
                    f"--collector.path={path} is neither a LeRobot checkpoint folder nor a "
                    f"TorchScript file: {exc}"
                ) from exc
            self._loaded = None

    def expert_for(self, task: str) -> Callable[[dict], np.ndarray]:
        import torch

        if self._module is not None:
            module, device = self._module, self.device

            def act_torchscript(observation: dict) -> np.ndarray:
                state = torch.as_tensor(
                    np.asarray(observation["environment_state"], np.float32)[None], device=device
                )
                with torch.inference_mode():
                    action = module(state)
                action = np.asarray(action.detach().cpu().numpy(), dtype=np.float64).reshape(-1)
                if action.shape != (self.suite.action_dim,):
                    raise AdaDemoError(
                        f"TorchScript expert {self.path} returned {action.size} values; "
                        f"the {self.suite.name} suite needs {self.suite.action_dim}"
                    )
                return action

            return act_torchscript

        from lerobot.envs.utils import preprocess_observation

        loaded = self._loaded
        loaded.policy.reset()  # a fresh action queue for every attempt
        description = self.suite.task_description(task)

        def act_lerobot(observation: dict) -> np.ndarray:
            batch = {
                "agent_pos": np.asarray(observation["agent_pos"])[None],
                "environment_state": np.asarray(observation["environment_state"])[None],
            }
            if "pixels" in observation:
                batch["pixels"] = {k: np.asarray(v)[None] for k, v in observation["pixels"].items()}
            batch = preprocess_observation(batch)
            batch["task"] = [description]
            with torch.inference_mode():
                batch = loaded.preprocessor(batch)
                action = loaded.postprocessor(loaded.policy.select_action(batch))
            return np.asarray(action.to("cpu").numpy(), dtype=np.float64).reshape(-1)

        return act_lerobot
