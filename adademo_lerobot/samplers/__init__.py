"""Episode-weighted sampling for training (paper principle C) behind one small protocol.

The torch `WeightedFrameSampler` is in `adademo_lerobot.samplers.weighted_sampler` (importing torch takes
seconds; the weights need only numpy)."""

from adademo_lerobot.samplers.weights import (
    SAMPLERS,
    FrameUniform,
    SamplingScheme,
    TaskUniform,
    Tempered,
    TrajectoryUniform,
    check_sampler_flags,
    floor_shares,
    frame_weights,
    make_sampling_scheme,
)

__all__ = [
    "SAMPLERS", "FrameUniform", "SamplingScheme", "TaskUniform", "Tempered", "TrajectoryUniform", "check_sampler_flags",
    "floor_shares", "frame_weights", "make_sampling_scheme",
]  # fmt: skip
