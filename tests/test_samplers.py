"""Sampler statistics: over many draws, task and trajectory frequencies match the formulas."""

import numpy as np
import pandas as pd
import pytest

from adademo_lerobot.core.errors import AdaDemoError
from adademo_lerobot.samplers import floor_shares, frame_weights, make_sampling_scheme
from adademo_lerobot.samplers.weighted_sampler import WeightedFrameSampler

# Three tasks with very different demo counts and episode lengths.
SPEC = {"easy": (2, 100), "mid": (6, 50), "hard": (12, 20)}  # task: (episodes, frames per episode)


def episodes_table() -> pd.DataFrame:
    rows, start = [], 0
    for task, (n, length) in SPEC.items():
        for _ in range(n):
            rows.append({"task": task, "dataset_from_index": start, "dataset_to_index": start + length})
            start += length
    return pd.DataFrame(rows)


def draw(weights: np.ndarray, n: int = 200_000, seed: int = 0) -> np.ndarray:
    return np.fromiter(iter(WeightedFrameSampler(weights, n, seed)), dtype=np.int64, count=n)


def shares_from_draws(indices: np.ndarray, eps: pd.DataFrame) -> tuple[pd.Series, np.ndarray]:
    episode_of_frame = np.repeat(
        np.arange(len(eps)), (eps.dataset_to_index - eps.dataset_from_index).to_numpy()
    )
    ep = episode_of_frame[indices]
    ep_freq = np.bincount(ep, minlength=len(eps)) / len(indices)
    task_freq = pd.Series(ep_freq).groupby(eps["task"].to_numpy()).sum()
    return task_freq, ep_freq


TOL = 0.01  # absolute tolerance on frequencies over 200k draws (std of a 1/3 share is ~0.001)


def test_trajectory_sampler_matches_n_k_over_sum_n():
    eps = episodes_table()
    w = frame_weights(make_sampling_scheme("trajectory", 0.0, 3), eps, int(eps.dataset_to_index.max()))
    task_freq, ep_freq = shares_from_draws(draw(w), eps)
    total = sum(n for n, _ in SPEC.values())
    for task, (n, _) in SPEC.items():
        assert abs(task_freq[task] - n / total) < TOL
    assert np.abs(ep_freq - 1 / len(eps)).max() < TOL  # every trajectory equally likely


def test_trajectory_floor_lifts_small_tasks_and_keeps_proportions():
    eps = episodes_table()
    floor = 0.25
    w = frame_weights(make_sampling_scheme("trajectory", floor, 3), eps, int(eps.dataset_to_index.max()))
    task_freq, _ = shares_from_draws(draw(w), eps)
    # easy has 2/20 = 0.10 < 0.25 -> pinned at 0.25; mid and hard share 0.75 as 6:12.
    expected = {"easy": 0.25, "mid": 0.75 * 6 / 18, "hard": 0.75 * 12 / 18}
    for task, share in expected.items():
        assert abs(task_freq[task] - share) < TOL, (task, task_freq[task], share)
    assert floor_shares({"a": 0.05, "b": 0.15, "c": 0.8}, 0.2) == pytest.approx(
        {"a": 0.2, "b": 0.2, "c": 0.6}
    )


def test_task_sampler_is_uniform_over_tasks_then_trajectories():
    eps = episodes_table()
    w = frame_weights(make_sampling_scheme("task", 0.0, 3), eps, int(eps.dataset_to_index.max()))
    task_freq, ep_freq = shares_from_draws(draw(w), eps)
    assert np.abs(task_freq.to_numpy() - 1 / 3).max() < TOL
    for i, row in eps.iterrows():
        assert abs(ep_freq[i] - 1 / 3 / SPEC[row.task][0]) < TOL


def test_frame_sampler_matches_frame_counts():
    eps = episodes_table()
    n_frames = int(eps.dataset_to_index.max())
    w = frame_weights(make_sampling_scheme("frame", 0.0, 3), eps, n_frames)
    np.testing.assert_allclose(w, 1 / n_frames)
    task_freq, _ = shares_from_draws(draw(w), eps)
    for task, (n, length) in SPEC.items():
        assert abs(task_freq[task] - n * length / n_frames) < TOL


def test_drop_last_frames_are_never_drawn_and_frames_uniform_within_episode():
    eps = episodes_table()
    w = frame_weights(make_sampling_scheme("trajectory", 0.0, 3), eps, int(eps.dataset_to_index.max()), 7)
    idx = draw(w, 50_000)
    for _, row in eps.iterrows():
        tail = np.arange(row.dataset_to_index - 7, row.dataset_to_index)
        assert not np.isin(idx, tail).any()
        assert w[row.dataset_from_index] == w[row.dataset_to_index - 8] > 0


def test_sampler_resume_skips_exactly_the_consumed_draws():
    w = np.arange(1, 101, dtype=np.float64)
    w /= w.sum()
    full = draw(w, 100_000, seed=3)
    resumed = np.fromiter(iter(WeightedFrameSampler(w, 30_000, seed=3, skip=70_000)), dtype=np.int64)
    np.testing.assert_array_equal(full[70_000:], resumed)


def test_bad_sampler_arguments():
    with pytest.raises(AdaDemoError, match="sampler"):
        make_sampling_scheme("weighted", 0.0, 3)
    with pytest.raises(AdaDemoError, match="min_task_weight"):
        make_sampling_scheme("trajectory", 0.5, 3)
    with pytest.raises(AdaDemoError, match="min_task_weight"):
        make_sampling_scheme("trajectory", -0.1, 3)


def test_tempered_interpolates_between_task_and_trajectory_uniform():
    from adademo_lerobot.samplers import Tempered

    tasks = ["a"] * 8 + ["b"] * 2
    lengths = [10] * 10
    for alpha, expected_a in ((1.0, 0.8), (0.0, 0.5), (0.5, 8**0.5 / (8**0.5 + 2**0.5))):
        probs = Tempered(alpha).episode_probabilities(tasks, lengths)
        assert abs(probs[:8].sum() - expected_a) < 1e-12 and abs(probs.sum() - 1) < 1e-12
        assert len(set(probs[:8])) == 1  # uniform over a task's trajectories
    np.testing.assert_allclose(
        Tempered(1.0).episode_probabilities(tasks, lengths),
        make_sampling_scheme("trajectory", 0.0, 2).episode_probabilities(tasks, lengths),
    )
    np.testing.assert_allclose(
        Tempered(0.0).episode_probabilities(tasks, lengths),
        make_sampling_scheme("task", 0.0, 2).episode_probabilities(tasks, lengths),
    )
    floored = Tempered(1.0, min_task_weight=0.3).episode_probabilities(tasks, lengths)
    assert abs(floored[8:].sum() - 0.3) < 1e-12  # the per-task floor still applies
    with pytest.raises(AdaDemoError, match="sampler_alpha"):
        make_sampling_scheme("tempered", 0.0, 2, alpha=-1)


def test_parts_of_episodes_are_weighted_and_keep_the_episode_end_for_dropped_frames():
    """LeRobot's DAgger data (`dataset/interventions.py`): parts of episodes with their weights; the frames
    Diffusion cannot train on are those before the end of the episode, not of the part."""
    parts = pd.DataFrame(
        {
            "task": ["a", "a", "a"],
            "dataset_from_index": [0, 4, 10],
            "dataset_to_index": [
                4,
                10,
                12,
            ],  # episode 0: frames 0-9 (person 0-3, policy 4-9); episode 1: 10-11
            "episode_to_index": [10, 10, 12],
            "weight": [1.0, 0.0, 1.0],
        }
    )
    w = frame_weights(make_sampling_scheme("trajectory", 0.0, 1), parts, 12)
    np.testing.assert_allclose(w, [0.125] * 4 + [0.0] * 6 + [0.25] * 2)
    w = frame_weights(
        make_sampling_scheme("trajectory", 0.0, 1), parts, 12, drop_n_last_frames=2
    )  # episode 1 has nothing left
    np.testing.assert_allclose(w, [0.25] * 4 + [0.0] * 8)
