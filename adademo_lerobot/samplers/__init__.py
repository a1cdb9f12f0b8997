"""Episode-weighted sampling for training (paper principle C) behind one small protocol."""

from adademo_lerobot.samplers.weighted_sampler import WeightedFrameSampler
from adademo_lerobot.samplers.weights import (
    SAMPLERS,
    FrameUniform,
    SamplingScheme,
    TaskUniform,
    Tempered,
    TrajectoryUniform,
    floor_shares,
    frame_weights,
    make_sampling_scheme,
)

__all__ = [
    "SAMPLERS", "FrameUniform", "SamplingScheme", "TaskUniform", "Tempered", "TrajectoryUniform", "WeightedFrameSampler",
    "floor_shares", "frame_weights", "make_sampling_scheme",
]  # fmt: skip
