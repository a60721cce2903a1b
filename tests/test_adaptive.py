"""KLD-sampling: the particle count a belief needs (estimator/adaptive.py)."""
import numpy as np
import pytest
from scipy.stats import chi2

from estimator.adaptive import coverage_min_particles, kld_bound, occupied_bins, particles_needed, region_coverage
from estimator.config import AdaptiveConfig


def test_the_bound_is_the_chi_square_quantile_over_twice_epsilon():
    k = np.array([2, 3, 5, 10, 30, 100, 300])
    exact = chi2.ppf(0.99, k - 1) / (2 * 0.05)
    # Wilson-Hilferty: within 1 % of the exact quantile for one degree of freedom, far closer beyond
    assert kld_bound(k, 0.05, 0.01) == pytest.approx(exact, rel=0.01)
    assert np.all(kld_bound(np.array([0, 1]), 0.05, 0.01) == 0.0)
    assert kld_bound(10, 0.1, 0.01) == pytest.approx(kld_bound(10, 0.05, 0.01) / 2)


def _kl_to_uniform(counts):
    n = counts.sum(axis=1, keepdims=True)
    p_hat = counts / n
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sum(np.where(counts > 0, p_hat * np.log(p_hat * counts.shape[1]), 0.0), axis=1)


def test_samples_of_the_bound_s_size_keep_the_divergence_under_epsilon_as_often_as_promised():
    # k equally likely bins, n = kld_bound(k) samples: 2 n KL(estimate || truth) is asymptotically
    # chi-square with k - 1 degrees of freedom, so KL > epsilon in a fraction delta of the trials; at
    # finite n Williams' factor q = 1 + (k + 1) / (6 n) scales the statistic. The observed rate must
    # lie within three binomial standard errors of that tail, and the tail within 15 % of delta
    rng = np.random.default_rng(11)
    eps, delta, trials = 0.05, 0.01, 20000
    for k in (4, 10, 20):
        n = int(np.ceil(kld_bound(k, eps, delta)))
        rate = np.mean(_kl_to_uniform(rng.multinomial(n, np.full(k, 1.0 / k), size=trials)) > eps)
        tail = chi2.sf(2 * n * eps / (1 + (k + 1) / (6 * n)), k - 1)
        assert abs(rate - tail) < 3 * np.sqrt(tail * (1 - tail) / trials)
        assert tail == pytest.approx(delta, rel=0.15)
        # and the bound is not loose: half as many samples break it far more often
        half = np.mean(_kl_to_uniform(rng.multinomial(n // 2, np.full(k, 1.0 / k), size=trials)) > eps)
        assert half > 5 * delta


def test_a_region_fitted_to_k_samples_covers_a_new_draw_as_often_as_hotelling_says():
    # k samples of a Gaussian, their mean and covariance, the chi-square region at the level; a new
    # draw of the same Gaussian falls in it at the rate region_coverage gives, within three binomial
    # standard errors (the Gaussian's own mean and covariance do not matter: the statistic is invariant)
    rng = np.random.default_rng(5)
    trials = 40000
    shape = np.array([[2.0, 0, 0], [0.5, 1.0, 0], [0, 0.3, 0.2]])
    for k, level, dim in ((8, 0.9, 3), (30, 0.5, 3), (12, 0.9, 2)):
        draws = rng.normal(size=(trials, k + 1, dim)) @ shape[:dim, :dim]
        x, new = draws[:, :k], draws[:, k]
        m = x.mean(axis=1)
        d = x - m[:, None]
        S = np.einsum("tki,tkj->tij", d, d) / (k - 1)
        r = new - m
        m2 = np.einsum("ti,ti->t", r, np.linalg.solve(S, r[..., None])[..., 0])
        rate = np.mean(m2 <= chi2.ppf(level, dim))
        p = float(region_coverage(k, level, dim))
        assert p < level and abs(rate - p) < 3 * np.sqrt(p * (1 - p) / trials)
    assert np.all(np.diff(region_coverage(np.arange(4, 2000))) > 0)
    assert region_coverage(10**6) == pytest.approx(0.9, abs=1e-5)
    with pytest.raises(ValueError):
        region_coverage(3, 0.9, 3)


def test_the_default_minimum_is_the_least_count_whose_regions_cover_within_a_point():
    n = coverage_min_particles()
    assert AdaptiveConfig().min_particles == n
    assert all(region_coverage(n, lv) >= lv - 0.01 for lv in (0.5, 0.9))
    assert any(region_coverage(n - 1, lv) < lv - 0.01 for lv in (0.5, 0.9))
    assert coverage_min_particles((0.9,)) <= n and coverage_min_particles((0.9,), 0.02) < coverage_min_particles((0.9,))
    with pytest.raises(ValueError):
        coverage_min_particles((0.9,), 0.95)


def test_bins_are_centred_on_the_mean_split_by_mode_and_ignore_light_or_missing_particles():
    rng = np.random.default_rng(2)
    K = 200
    w = np.full(K, 1.0 / K)
    tight = np.array([0.31, -0.77, 0.66]) + rng.normal(0, 0.005, (K, 3))  # 5 mm around any point
    modes = np.zeros(K, int)
    assert occupied_bins(tight, modes, w, 0.05, 0.5 / K) == 1
    two = tight.copy()
    two[K // 2:, 0] += 0.3  # two places 30 cm apart
    assert occupied_bins(two, modes, w, 0.05, 0.5 / K) == 2
    held = modes.copy()
    held[:10] = 1  # a held hypothesis at the same place is its own bin
    assert occupied_bins(tight, held, w, 0.05, 0.5 / K) == 2
    light = two.copy()
    wl = np.where(np.arange(K) < K // 2, 1.0, 1e-6)
    wl /= wl.sum()  # the second place carries almost no weight: not counted
    assert occupied_bins(light, modes, wl, 0.05, 0.5 / K) == 1
    nan = tight.copy()
    nan[:5] = np.nan
    assert occupied_bins(nan, modes, w, 0.05, 0.5 / K) == 1
    assert occupied_bins(np.full((3, 3), np.nan), np.zeros(3, int), np.full(3, 1 / 3), 0.05, 0.1) == 0


def test_the_count_is_the_largest_over_the_objects_clipped_to_the_bounds():
    rng = np.random.default_rng(5)
    K, M = 100, 3
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    poses[:, 1, :3] = rng.normal(0, 0.002, (K, 3))  # seen, at rest
    poses[:, 2, :2] = rng.uniform(-0.2, 0.2, (K, 2))  # hidden somewhere on a 40 cm square
    modes = np.zeros((K, M), int)
    w = np.full(K, 1.0 / K)
    cfg = AdaptiveConfig(enabled=True, min_particles=16, max_particles=4096)
    only_seen = np.array([False, True, False])
    n, bins = particles_needed(poses, modes, w, only_seen, cfg)
    assert n == 16 and bins.tolist() == [0, 1, 0]
    n, bins = particles_needed(poses, modes, w, np.array([False, True, True]), cfg)
    assert bins[2] >= 40  # an 8 x 8 grid of 5 cm bins, most of it occupied
    assert n == int(np.ceil(kld_bound(bins[2], cfg.epsilon, cfg.delta)))
    small = AdaptiveConfig(enabled=True, min_particles=16, max_particles=200)
    assert particles_needed(poses, modes, w, np.array([False, True, True]), small)[0] == 200
    with pytest.raises(ValueError):
        particles_needed(poses, modes[:, :2], w, only_seen, cfg)


def test_the_configuration_is_checked():
    with pytest.raises(ValueError):
        AdaptiveConfig(min_particles=1)
    with pytest.raises(ValueError):
        AdaptiveConfig(min_particles=64, max_particles=32)
    with pytest.raises(ValueError):
        AdaptiveConfig(delta=0.0)
    with pytest.raises(ValueError):
        AdaptiveConfig(bin_size=-0.05)
    with pytest.raises(ValueError):
        AdaptiveConfig(enabled="yes")
