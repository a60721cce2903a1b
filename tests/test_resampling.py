import numpy as np
import pytest

from estimator.resampling import (
    effective_sample_size,
    keep_survivors_in_place,
    multinomial_resample,
    normalise_log_weights,
    split_ancestors,
    systematic_resample,
)


def test_normalise_handles_infinities_and_collapse():
    w, logz = normalise_log_weights(np.array([0.0, np.log(3.0), -np.inf, np.nan]))
    assert np.allclose(w, [0.25, 0.75, 0, 0]) and np.isclose(logz, np.log(4 / 4))
    w, logz = normalise_log_weights(np.array([-1e308, -np.inf]))
    assert np.allclose(w, [1, 0])
    w, logz = normalise_log_weights(np.full(3, -np.inf))
    assert np.allclose(w, 1 / 3) and logz == -np.inf
    w, _ = normalise_log_weights(np.array([-1000.0, -1001.0]))  # no underflow
    assert np.isclose(w[0] / w[1], np.e)


def test_ess():
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10)
    assert effective_sample_size(np.eye(1, 10)[0]) == pytest.approx(1)


@pytest.mark.parametrize("scheme", [systematic_resample, multinomial_resample])
def test_resampling_counts_match_weights(scheme):
    rng = np.random.default_rng(7)
    w = np.array([0.5, 0.3, 0.15, 0.05])
    k, reps = len(w), 4000
    counts = np.zeros(k)
    for _ in range(reps):
        counts += np.bincount(scheme(w, rng), minlength=k)
    freq = counts / (reps * k)
    se = np.sqrt(w * (1 - w) / (reps * k))  # multinomial bound; systematic is tighter
    assert np.all(np.abs(freq - w) < 4 * se + 1e-12)


def test_systematic_never_returns_k_despite_round_off():
    rng = np.random.default_rng(0)
    w = np.full(7, 1 / 7)
    w[-1] -= 1e-16  # a cumulative sum that ends just under 1
    for _ in range(200):
        idx = systematic_resample(w, rng)
        assert idx.min() >= 0 and idx.max() < 7
    # systematic resampling keeps each particle floor(K w) or ceil(K w) times
    counts = np.bincount(systematic_resample(np.array([0.55, 0.45]), rng), minlength=2)
    assert counts.tolist() in ([1, 1],)


def test_keep_survivors_in_place_permutes_the_ancestors():
    """Same counts per ancestor; every survivor sits in its own slot; extra copies fill the others."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        k = int(rng.integers(1, 40))
        w = rng.dirichlet(np.full(k, 0.3))
        anc = systematic_resample(w, rng)
        out = keep_survivors_in_place(anc)
        assert np.array_equal(np.bincount(out, minlength=k), np.bincount(anc, minlength=k))
        survivors = np.unique(anc)
        assert np.all(out[survivors] == survivors)
    assert list(keep_survivors_in_place(np.array([0, 0, 2, 3, 3, 3]))) == [0, 0, 2, 3, 3, 3]
    assert list(keep_survivors_in_place(np.array([2, 2, 2, 2, 3]))) == [2, 2, 2, 3, 2]


def test_resampling_to_another_count_keeps_the_weights_proportions_and_survivors_in_place():
    rng = np.random.default_rng(8)
    w = np.array([0.5, 0.3, 0.15, 0.05])
    for n in (1, 3, 10, 40):
        anc = systematic_resample(w, rng, n)
        assert len(anc) == n and anc.min() >= 0 and anc.max() < 4
        # systematic: each particle kept floor(n w) or ceil(n w) times
        counts = np.bincount(anc, minlength=4)
        assert np.all(counts >= np.floor(n * w)) and np.all(counts <= np.ceil(n * w))
        out = keep_survivors_in_place(anc)
        assert np.array_equal(np.bincount(out, minlength=4), counts)
        kept = np.unique(anc[anc < n])
        assert np.all(out[kept] == kept)
    assert keep_survivors_in_place(np.array([5, 5, 1])).tolist() == [5, 1, 5]
    with pytest.raises(ValueError):
        systematic_resample(w, rng, 0)


def test_splitting_keeps_every_particle_in_place_and_every_weighted_average():
    """Growing 10 particles to 37: the first 10 entries are the particles themselves, each one's weight
    is shared equally among it and its copies (so every weighted average is the same, to round-off),
    and the 27 copies are spread by weight: systematic resampling gives particle i floor or ceil of
    27 w_i of them."""
    rng = np.random.default_rng(11)
    w = rng.dirichlet(np.ones(10))
    w[3] = 0.0
    w /= w.sum()
    anc, nw = split_ancestors(w, np.random.default_rng(12), 37)
    assert anc.shape == nw.shape == (37,) and np.array_equal(anc[:10], np.arange(10))
    assert np.all(np.diff(anc[10:]) >= 0)
    assert np.allclose(np.bincount(anc, weights=nw, minlength=10), w, rtol=0, atol=1e-15)
    values = rng.normal(size=10)
    assert np.isclose(nw @ values[anc], w @ values, rtol=0, atol=1e-12)
    extra = np.bincount(anc[10:], minlength=10)
    assert np.all((extra >= np.floor(27 * w) - 1e-9) & (extra <= np.ceil(27 * w) + 1e-9)) and extra[3] == 0
    counts = np.bincount(anc, minlength=10)
    assert np.allclose(nw, w[anc] / counts[anc]) and np.isclose(nw.sum(), 1.0)
    with pytest.raises(ValueError, match="n > 10"):
        split_ancestors(w, rng, 10)
