"""'Will AdaDemo help on this task?': the failure-predictability score on outcomes whose answer is known."""

import numpy as np

from adademo_lerobot.loop.failure_map import auc, predictability


def test_auc_is_the_probability_a_failure_outscores_a_success():
    assert auc(np.array([0.9, 0.8, 0.1, 0.2]), np.array([1, 1, 0, 0])) == 1.0
    assert auc(np.array([0.1, 0.2, 0.9, 0.8]), np.array([1, 1, 0, 0])) == 0.0
    assert auc(np.array([0.5, 0.5, 0.5, 0.5]), np.array([1, 0, 1, 0])) == 0.5  # ties count half


def test_failures_in_one_region_are_predictable_and_random_ones_are_not():
    rng = np.random.default_rng(0)
    states = rng.uniform(-1, 1, size=(200, 3))
    region = predictability("t", [(states, states[:, 0] > 0.3)])
    assert region.auc > 0.9 and region.low > 0.8
    assert region.reading.startswith("failures concentrate")
    coin = predictability("t", [(states, rng.random(200) < 0.4)])
    assert abs(coin.auc - 0.5) < 0.15 and coin.low < 0.5 < coin.high
    assert coin.reading.startswith("failures look independent")
    few = predictability("t", [(states[:20], np.arange(20) < 2)])  # 2 failures
    assert few.auc is None and few.reading == "too few outcomes to tell"
    solved = predictability("t", [(states[:50], np.arange(50) < 1)])  # 1 failure in 50: already solved
    assert solved.auc is None and solved.reading.startswith("(almost) never fails")
    always = predictability("t", [(states[:50], np.arange(50) < 48)])  # 2 successes: no reading either way
    assert always.reading == "too few outcomes to tell"
