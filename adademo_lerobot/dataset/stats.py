"""An episode's stats as LeRobot computes them, without its 5,000-bin histograms.

LeRobot's `compute_episode_stats` feeds each feature's frames to a `RunningQuantileStats` in one batch, which
builds a 5,000-bin histogram per dimension and then, per quantile, a cumulative sum over the bins: ~80% of
writing a 70-frame state episode (a profile of 40 MetaWorld shard writes, 2026-12-05). For one batch the same quantiles follow from
the few bins that hold a value: a value's bin is where it falls among the same edges, and a cumulative count at a
bin is how many values lie in bins up to it. The edges, the arithmetic and the scalar types are LeRobot's, so the
stats are bit for bit the same (`tests/test_stats.py` compares them with LeRobot's own on random and recorded
data). Used while an episode is written (a worker's shard, an append); listed in docs/lerobot-overrides.md.
"""

from __future__ import annotations

import math

import numpy as np
from lerobot.datasets import compute_stats
from lerobot.datasets.compute_stats import RunningQuantileStats

from adademo_lerobot.core.patching import temporarily_set


class OneBatchQuantileStats(RunningQuantileStats):
    """`RunningQuantileStats` fed exactly one batch (as `get_feature_stats` does): per dimension it keeps the sorted
    bin index of each value instead of adding them into a histogram."""

    _sorted_bins: list[np.ndarray] | None = None

    def _update_histograms(self, batch: np.ndarray) -> None:
        if self._sorted_bins is not None or self._count != len(batch):
            raise RuntimeError("OneBatchQuantileStats takes one batch; LeRobot's stats now feed it several")
        self._sorted_bins = []
        for i, edges in enumerate(self._bin_edges):
            values = batch[:, i]
            # np.histogram's bins (given edges): [e[j], e[j+1]), the last one closed; values outside count nowhere.
            inside = values[(values >= edges[0]) & (values <= edges[-1])]
            self._sorted_bins.append(np.sort(np.searchsorted(edges[1:-1], inside, side="right")))

    def _compute_quantiles(self) -> list[np.ndarray]:
        results = []
        for q in self._quantile_list:
            target_count = q * self._count
            values = [
                _quantile(bins, edges, target_count)
                for bins, edges in zip(self._sorted_bins, self._bin_edges, strict=True)
            ]
            results.append(np.array(values))
        return results


def _quantile(sorted_bins: np.ndarray, edges: np.ndarray, target_count: float):
    """`RunningQuantileStats._compute_single_quantile` of the histogram whose values fall in `sorted_bins`: the
    first bin whose cumulative count reaches `target_count`, interpolated within it (the same float64 counts,
    the same operations, so the same result and scalar type)."""
    if target_count <= 0:
        return edges[0]
    needed = math.ceil(target_count)  # cumulative counts are whole numbers
    if needed > len(sorted_bins):
        return edges[-1]
    idx = int(sorted_bins[needed - 1])
    if idx == 0:
        return edges[0]
    count_before = np.float64(np.searchsorted(sorted_bins, idx, side="left"))
    count_in_bin = np.float64(np.searchsorted(sorted_bins, idx, side="right")) - count_before
    fraction = (target_count - count_before) / count_in_bin
    return edges[idx] + fraction * (edges[idx + 1] - edges[idx])


def lerobot_stats_by_value_bins():
    """While it is open, LeRobot's episode stats are computed with `OneBatchQuantileStats` (same results)."""
    return temporarily_set(compute_stats, "RunningQuantileStats", OneBatchQuantileStats)


def episode_stats(episode: dict, features: dict) -> dict:
    """LeRobot's `compute_episode_stats(episode, features)`, computed with `OneBatchQuantileStats`."""
    with lerobot_stats_by_value_bins():
        return compute_stats.compute_episode_stats(episode, features)
