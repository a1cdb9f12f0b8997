"""Every random draw of the tool is a named stream of seeds derived from the user's seed.

Each stream has its own key, so the fixed evaluation set, the initial collection, the states an expansion round
evaluates and the retries of an expert never share an initial state, and the same seed gives the same draws on
any machine, with any executor and any number of workers.
"""

from __future__ import annotations

import zlib

import numpy as np


def derive_seed(*keys: int | str) -> int:
    """A stable 63-bit seed from a tuple of ints and strings (strings hashed with CRC32, stable across runs)."""
    ints = [k if isinstance(k, int) else zlib.crc32(k.encode()) for k in keys]
    high, low = np.random.SeedSequence(ints).generate_state(2, dtype=np.uint32)
    return (int(high) << 31) | (int(low) >> 1)


def fresh_state_seed(seed: int, round_index: int, task: str, draw: int) -> int:
    """The `draw`-th fresh random initial state of `task` in a round (initial collection, Uniform, ablation A)."""
    return derive_seed(seed, "fresh", round_index, task, draw)


def expansion_state_seed(seed: int, round_index: int, task: str, k: int) -> int:
    """The k-th initial state Algorithm 1 samples for `task` in a round (line 8)."""
    return derive_seed(seed, "expand", round_index, task, k)


def plan_state_seeds(seed: int, round_index: int, task: str, n: int) -> list[int]:
    """The states ablation A and `--plan_only` evaluate to estimate a task's success rate."""
    return [derive_seed(seed, "plan", round_index, task, k) for k in range(n)]


def evaluation_seeds(seed: int, task: str, n: int) -> list[int]:
    """The fixed evaluation set: the same every round and for every strategy, never used for collection."""
    return [derive_seed(seed, "eval", task, k) for k in range(n)]


def retry_noise_seed(state_seed: int, attempt: int) -> int:
    """The action noise of an expert's retry from the same initial state."""
    return derive_seed(state_seed, "retry", attempt)
