"""An episode's stats as LeRobot computes them, without its 5,000-bin histograms.

LeRobot's `compute_episode_stats` feeds each feature's frames to a `RunningQuantileStats` in one batch, which
builds a 5,000-bin histogram per dimension and then, per quantile, a cumulative sum over the bins: ~80% of
writing a 70-frame state episode (a profile of 40 MetaWorld shard writes, 2026-12-05). For one batch the same
quantiles follow from the few bins that hold a value: a value's bin is where it falls among the same edges, and a
cumulative count at a bin is how many values lie in bins up to it; all dimensions of a feature are done at once,
so that a 40-dimension state costs about what a scalar does. The edges, the arithmetic and the scalar types are
LeRobot's, so the stats are bit for bit the same (`tests/test_stats.py` compares them with LeRobot's own on random
and recorded data). Used while an episode is written (a worker's shard, an append); listed in
docs/lerobot-overrides.md.
"""

from __future__ import annotations

import math

import numpy as np
from lerobot.datasets import compute_stats
from lerobot.datasets.compute_stats import RunningQuantileStats

from adademo_lerobot.core.patching import temporarily_set


class OneBatchQuantileStats(RunningQuantileStats):
    """`RunningQuantileStats` fed exactly one batch (as `get_feature_stats` does), all dimensions at once: each
    value's bin among the edges LeRobot's histogram would have, those edges computed only where they are read.
    A batch with a NaN or an infinity goes through LeRobot's own histograms."""

    _sorted_bins: np.ndarray | None = None  # (values, dimensions): each column's bin indices, in order

    def update(self, batch: np.ndarray) -> None:
        if self._count:
            raise RuntimeError("OneBatchQuantileStats takes one batch; LeRobot's stats now feed it several")
        values = batch.reshape(-1, batch.shape[-1])
        values = values.astype(np.result_type(values.dtype, np.float32), copy=False)
        if not np.isfinite(values).all():
            return super().update(batch)
        # LeRobot's first update without its per-dimension histograms.
        self._mean, self._mean_of_squares = np.mean(values, axis=0), np.mean(values**2, axis=0)
        self._min, self._max = np.min(values, axis=0), np.max(values, axis=0)
        self._count = len(values)
        # It then folds the same batch in again, adding (mean - mean) * 1, a 0.0 (which turns a -0.0 mean into 0.0).
        self._mean += 0.0
        self._mean_of_squares += 0.0
        # np.linspace(min - 1e-10, max + 1e-10, bins + 1) of each dimension, as its own arithmetic gives them.
        self._first, self._last = self._min - 1e-10, self._max + 1e-10
        self._step = (self._last - self._first) / self._num_quantile_bins
        self._sorted_bins = self._bins_of(np.sort(values, axis=0))

    def _edge(self, index: np.ndarray) -> np.ndarray:
        """LeRobot's bin edges at `index` (one index per dimension, in the last axis): linspace's `i * step +
        start` in the dimension's dtype, and the last edge exactly the stop."""
        edge = index.astype(self._first.dtype) * self._step + self._first
        return np.where(index == self._num_quantile_bins, self._last, edge)

    def _bins_of(self, ordered: np.ndarray) -> np.ndarray:
        """np.histogram's bin of each value ([e[j], e[j+1]), the last one closed): the number of interior edges at
        or below it. Guessed by arithmetic, then moved until the exact edges agree; a column still moving after a
        few moves (its edges repeat for many indices: a narrow range in float32) is searched among all its edges."""
        top = self._num_quantile_bins - 1
        with np.errstate(divide="ignore", invalid="ignore"):
            guess = np.floor((ordered - self._first) / self._step)
        bins = np.where(np.isfinite(guess), np.clip(guess, 0, top), top).astype(np.intp)
        for _ in range(4):
            up = (bins < top) & (self._edge(bins + 1) <= ordered)
            down = (bins > 0) & (self._edge(bins) > ordered)
            moving = (up | down).any(axis=0)
            if not moving.any():
                return bins
            bins += up.astype(np.intp) - down
        for i in np.flatnonzero(moving):
            edges = np.linspace(self._first[i], self._last[i], self._num_quantile_bins + 1)  # LeRobot's own
            bins[:, i] = np.searchsorted(edges[1:-1], ordered[:, i], side="right")
        return bins

    def _compute_quantiles(self) -> list[np.ndarray]:
        """`RunningQuantileStats._compute_single_quantile` for every quantile and dimension at once: the first
        bin whose cumulative count reaches the target, interpolated within it (the same float64 counts, the same
        operations and dtypes, so the same results)."""
        if self._sorted_bins is None:
            return super()._compute_quantiles()
        bins = self._sorted_bins
        targets = [q * self._count for q in self._quantile_list]
        # Cumulative counts are whole numbers: the bin of the ceil(target)-th value, when there is one.
        read = [t for t in targets if t > 0 and math.ceil(t) <= len(bins)]
        idx = bins[[math.ceil(t) - 1 for t in read]]  # (quantiles read, dimensions)
        count_before = (bins[None] < idx[:, None]).sum(axis=1).astype(np.float64)
        count_in_bin = (bins[None] <= idx[:, None]).sum(axis=1) - count_before
        low = self._edge(idx)
        fraction = (np.array(read)[:, None] - count_before) / count_in_bin
        values = np.where(idx == 0, self._first, low + fraction * (self._edge(idx + 1) - low))
        results, read_rows = [], iter(zip(idx, values, strict=True))
        for target in targets:
            if target <= 0 or math.ceil(target) > len(bins):
                results.append((self._first if target <= 0 else self._last).copy())
                continue
            bin_row, value = next(read_rows)
            # LeRobot returns the first edge itself for bin 0: its dtype too when every dimension does.
            results.append(value if bin_row.any() else self._first.copy())
        return results


def lerobot_stats_by_value_bins():
    """While it is open, LeRobot's episode stats are computed with `OneBatchQuantileStats` (same results)."""
    return temporarily_set(compute_stats, "RunningQuantileStats", OneBatchQuantileStats)


def episode_stats(episode: dict, features: dict) -> dict:
    """LeRobot's `compute_episode_stats(episode, features)`, computed with `OneBatchQuantileStats`."""
    with lerobot_stats_by_value_bins():
        return compute_stats.compute_episode_stats(episode, features)
