"""An episode's stats as we compute them (`dataset/stats.py`) are LeRobot's own, bit for bit: every stat, shape and
dtype, on random data built to hit the histogram's corners and on recorded MetaWorld episodes."""

from __future__ import annotations

import numpy as np
import pytest
from lerobot.datasets import compute_stats
from lerobot.utils.constants import DEFAULT_FEATURES

from adademo_lerobot.collectors import make_collector
from adademo_lerobot.collectors.scripted import ScriptedCollectorConfig
from adademo_lerobot.dataset.features import dataset_features
from adademo_lerobot.dataset.shards import episode_buffer
from adademo_lerobot.dataset.stats import OneBatchQuantileStats, episode_stats, lerobot_stats_by_value_bins
from adademo_lerobot.suites import make_suite
from adademo_lerobot.suites.metaworld import MetaWorldSuiteConfig


def assert_same_stats(ours: dict, stock: dict) -> None:
    assert ours.keys() == stock.keys()
    for key in stock:
        assert np.asarray(ours[key]).dtype == np.asarray(stock[key]).dtype, key
        np.testing.assert_array_equal(ours[key], stock[key], err_msg=key, strict=True)
        assert np.asarray(ours[key]).tobytes() == np.asarray(stock[key]).tobytes(), key  # -0.0 and NaNs too


def both(array: np.ndarray, axis=0, keepdims: bool = False) -> tuple[dict, dict]:
    stock = compute_stats.get_feature_stats(array, axis=axis, keepdims=keepdims)
    with lerobot_stats_by_value_bins():
        ours = compute_stats.get_feature_stats(array, axis=axis, keepdims=keepdims)
    assert compute_stats.RunningQuantileStats is not OneBatchQuantileStats  # put back after the block
    return ours, stock


def corner_cases(rng: np.random.Generator) -> list[np.ndarray]:
    n = 67
    uniform = rng.uniform(-1, 1, (n, 5))
    ties = rng.integers(0, 4, (n, 3)).astype(np.float64)  # many values share a bin
    constant = np.full((n, 2), 0.25)  # all edges equal in float32, nearly so in float64
    offset = 1e6 + rng.normal(0, 1e-3, (n, 2))  # min - 1e-10 == min: values on the outer edges
    skewed = np.concatenate([np.zeros((n - 2, 1)), [[1.0], [1e4]]])  # most values in bin 0
    cases = [uniform, ties, constant, offset, skewed]
    cases += [c.astype(np.float32) for c in cases]
    # Values exactly on interior edges: LeRobot's own edges for a column, used as the data.
    stock = compute_stats.RunningQuantileStats()
    stock.update(uniform[:, :1])
    on_edges = rng.choice(stock._bin_edges[0], size=(n, 1))
    on_edges[:2, 0] = stock._bin_edges[0][[0, -1]]
    cases += [
        on_edges,
        rng.integers(-5, 50, (n, 4)),  # int64, promoted to float64 as LeRobot does
        rng.uniform(0, 1, (2, 3)),  # the fewest frames a quantile is computed for
        rng.uniform(0, 1, (3, 3)).astype(np.float32),
        rng.normal(0, 1, (1001, 4)),
        np.full((n, 2), -0.0),
        # a mean that rounds to -0.0, which LeRobot's second fold of the batch makes 0.0
        np.array([[-5e-324], [0.0], [0.0]]),
        rng.uniform(-1e300, 1e300, (n, 2)),
        # float32 near 1e7, or a narrow range: hundreds of edges share a value (searched among all edges)
        (1e7 + rng.uniform(0, 2, (n, 3))).astype(np.float32),
        np.column_stack([0.6 + rng.uniform(0, 3e-7, n), rng.uniform(0, 1, n)]).astype(np.float32),
        np.where(rng.uniform(size=(n, 3)) < 0.1, np.nan, rng.uniform(size=(n, 3))),
        np.where(rng.uniform(size=(n, 3)) < 0.1, -np.inf, rng.uniform(size=(n, 3))),
    ]
    return cases


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_feature_stats_equal_lerobots(seed: int):
    rng = np.random.default_rng(seed)
    for array in corner_cases(rng):
        assert_same_stats(*both(array))
    assert_same_stats(*both(rng.uniform(0, 1, 40), keepdims=True))  # a 1-D feature (timestamps, indices)
    images = rng.integers(0, 256, (6, 3, 8, 8), dtype=np.uint8)  # per-channel stats of sampled images
    assert_same_stats(*both(images, axis=(0, 2, 3), keepdims=True))


def test_feature_stats_equal_lerobots_over_ranges_and_magnitudes():
    """Ranges from 1e-9 to 1e2 around values up to 1e7, float32 and float64, some rounded (ties): edges that are
    all distinct, and edges that repeat for hundreds of indices."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        n, d = int(rng.integers(2, 200)), int(rng.integers(1, 6))
        scale, centre = 10.0 ** rng.uniform(-9, 2, d), rng.uniform(-5, 5, d) * 10.0 ** rng.uniform(-3, 7, d)
        array = centre + rng.uniform(0, 1, (n, d)) * scale
        array = np.round(array, int(rng.integers(0, 4))) if rng.uniform() < 0.3 else array
        assert_same_stats(*both(array.astype(np.float32) if rng.uniform() < 0.6 else array))


def test_recorded_episodes_stats_equal_lerobots():
    suite = make_suite(MetaWorldSuiteConfig(tasks="reach-v3,push-v3,drawer-open-v3", max_episode_steps=200))
    collector = make_collector(ScriptedCollectorConfig(), suite)
    features = {**dataset_features(suite), **DEFAULT_FEATURES}
    for i, task in enumerate(suite.tasks * 2):
        demo = collector.collect(task, suite.sample_initial_state(task, i), i).demonstration
        episode = episode_buffer(demo, features, suite.fps)
        assert_same_stats_by_feature(
            episode_stats(episode, features), compute_stats.compute_episode_stats(episode, features)
        )


def assert_same_stats_by_feature(ours: dict, stock: dict) -> None:
    assert ours.keys() == stock.keys()
    for feature in stock:
        assert_same_stats(ours[feature], stock[feature])


def test_finite_batches_take_one_pass_and_the_rest_lerobots_histograms():
    """All dimensions of a finite batch at once (edges that repeat included); a NaN or an infinity goes through
    LeRobot's own histograms (their results are compared above)."""
    rng = np.random.default_rng(0)
    for batch in (rng.uniform(-1, 1, (70, 40)), (1e7 + rng.uniform(0, 2, (70, 3))).astype(np.float32)):
        stats = OneBatchQuantileStats()
        stats.update(batch)
        assert stats._sorted_bins.shape == batch.shape and stats._histograms is None
    for batch in (
        np.array([[0.0, 1.0], [np.nan, 2.0], [1.0, 3.0]]),
        np.array([[0.0, 1.0], [np.inf, 2.0], [1.0, 3.0]]),
    ):
        stats = OneBatchQuantileStats()
        stats.update(batch)
        assert stats._sorted_bins is None and len(stats._histograms) == batch.shape[1]


def test_more_than_one_batch_is_refused():
    """LeRobot's episode stats feed one batch; if a later LeRobot fed several, our quantiles would be wrong."""
    stats = OneBatchQuantileStats()
    stats.update(np.zeros((4, 2)))
    with pytest.raises(RuntimeError, match="one batch"):
        stats.update(np.ones((4, 2)))
