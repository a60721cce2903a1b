"""estimator.model.params: Liu-West shrinkage of the physical parameters."""
import math

import numpy as np

from estimator.model.params import LOG_COLUMNS, shrink_params, world_params


def test_liu_west_shrinkage_keeps_mean_and_spread():
    rng = np.random.default_rng(8)
    p = rng.uniform(0.3, 1.0, (4000, 1, 5))
    q = shrink_params(p, 0.1, np.array([[0.0, np.inf]] * 5), np.random.default_rng(9))
    assert np.allclose(q.mean(axis=0), p.mean(axis=0), atol=4 * 0.1 * p.std() / math.sqrt(4000))
    assert np.allclose(q.std(axis=0) / p.std(axis=0), 1.0, atol=0.03)
    assert np.all(np.abs(q - p) < 0.25) and np.any(q != p)
    clipped = shrink_params(p, 0.5, np.array([[0.4, 0.9]] * 5), np.random.default_rng(9))
    assert clipped.min() >= 0.4 and clipped.max() <= 0.9


def test_shrinkage_of_some_rows_towards_the_weighted_mean_leaves_the_others_alone():
    """Only ``rows`` are shrunk, towards the mean and std under ``weights``: 3000 new copies of 1000
    weighted particles (the last 3000 rows, drawn from them by weight) have the weighted mean, within
    four standard errors (sd / sqrt(3000): the draws', the shrinkage keeping the spread), and its
    spread; the 1000 are untouched."""
    rng = np.random.default_rng(3)
    base = rng.uniform(0.3, 1.0, (1000, 1, 5))
    w = rng.dirichlet(np.ones(1000))
    p = np.concatenate([base, base[rng.choice(1000, 3000, p=w)]])
    weights = np.concatenate([w, np.zeros(3000)])
    rows = np.arange(4000) >= 1000
    q = shrink_params(p, 0.1, np.array([[0.0, np.inf]] * 5), np.random.default_rng(4), rows=rows, weights=weights)
    assert np.array_equal(q[:1000], p[:1000]) and np.all(q[1000:] != p[1000:])
    cols = list(LOG_COLUMNS)  # shrunk as logs
    base, q = base.copy(), q.copy()
    base[..., cols], q[..., cols] = np.log(base[..., cols]), np.log(q[..., cols])
    mean = np.tensordot(w, base, axes=1)
    sd = np.sqrt(np.tensordot(w, (base - mean) ** 2, axes=1))
    assert np.all(np.abs(q[1000:].mean(axis=0) - mean) < 4 * sd / math.sqrt(3000))  # draws, then shrinkage: sd^2 / n
    assert np.allclose(q[1000:].std(axis=0) / sd, 1.0, atol=4 / math.sqrt(2 * 3000))


def test_the_worlds_get_each_rolling_friction_divided_by_what_the_object_rests_in_or_on():
    """Objects: a static table (friction 1.0), a crate (0.5 in particle 0, 0.8 in particle 1), a
    ball (rolling friction 0.002). Particle 0: the ball in the crate, whose box also overlaps the
    table's (the crate's floor holds it); particle 1: on the floor; particle 2: on the table and
    the crate at once (the mean); particle 3: on nothing (in the air): its own."""
    from physics.settings import FLOOR_FRICTION

    params = np.tile([[1.0, 0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.1, 1.0], [0.5, 0.002, 0.0, 0.2, 0.05]], (4, 1, 1))
    params[1, 1, 0] = 0.8
    on_top = np.zeros((4, 3, 4), bool)
    is_in = np.zeros((4, 3, 3), bool)
    on_top[0, 2, 0] = is_in[0, 2, 1] = True
    on_top[1, 2, 3] = True
    on_top[2, 2, 0] = on_top[2, 2, 1] = True
    out = world_params(params, on_top, is_in)
    assert np.allclose(out[:, 2, 1], [0.002 / 0.5, 0.002 / FLOOR_FRICTION, 0.002 / 0.75, 0.002])
    assert np.array_equal(np.delete(out, 1, axis=2), np.delete(params, 1, axis=2))
    assert params[0, 2, 1] == 0.002  # the particles' own parameters are what the scene states
    nothing = np.zeros_like(on_top)
    assert world_params(params, nothing, np.zeros_like(is_in)) is params
