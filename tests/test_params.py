"""estimator.model.params: Liu-West shrinkage of the physical parameters."""
import math

import numpy as np

from estimator.model.params import shrink_params


def test_liu_west_shrinkage_keeps_mean_and_spread():
    rng = np.random.default_rng(8)
    p = rng.uniform(0.3, 1.0, (4000, 1, 5))
    q = shrink_params(p, 0.1, np.array([[0.0, np.inf]] * 5), np.random.default_rng(9))
    assert np.allclose(q.mean(axis=0), p.mean(axis=0), atol=4 * 0.1 * p.std() / math.sqrt(4000))
    assert np.allclose(q.std(axis=0) / p.std(axis=0), 1.0, atol=0.03)
    assert np.all(np.abs(q - p) < 0.25) and np.any(q != p)
    clipped = shrink_params(p, 0.5, np.array([[0.4, 0.9]] * 5), np.random.default_rng(9))
    assert clipped.min() >= 0.4 and clipped.max() <= 0.9
