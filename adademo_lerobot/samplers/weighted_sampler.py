"""A with-replacement frame sampler whose draw sequence is a pure function of (weights, seed).

Resuming at training step s skips the first s * batch_size draws, so an interrupted run sees exactly the
batches it would have seen (the sampler's RNG state is recomputed, not stored).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

CHUNK = 65_536


class WeightedFrameSampler(torch.utils.data.Sampler[int]):
    def __init__(self, weights: np.ndarray, num_samples: int, seed: int, skip: int = 0):
        self.weights = torch.as_tensor(weights, dtype=torch.float64)
        self.num_samples = num_samples
        self.seed = seed
        self.skip = skip

    def __len__(self) -> int:
        return self.num_samples

    def __iter__(self) -> Iterator[int]:
        generator = torch.Generator().manual_seed(self.seed)
        position, emitted = 0, 0
        while emitted < self.num_samples:
            chunk = torch.multinomial(self.weights, CHUNK, replacement=True, generator=generator)
            begin = max(0, self.skip - position)
            position += CHUNK
            for index in chunk[begin:].tolist():
                yield index
                emitted += 1
                if emitted >= self.num_samples:
                    return
