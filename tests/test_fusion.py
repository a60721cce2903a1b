"""The ensemble Kalman step of resting objects (estimator.model.fusion)."""
import numpy as np
import pytest

from estimator.model.fusion import ensemble_kalman_step, shift_inconsistent, weighted_axis_variance


def test_one_step_gives_the_kalman_posterior_in_mean_and_variance():
    rng = np.random.default_rng(0)
    K, p0, r, d = 20000, 0.01 ** 2, 0.004 ** 2, np.array([[0.006, -0.003]])
    x = rng.normal(0.0, np.sqrt(p0), (K, 1, 2))
    w = np.full(K, 1.0 / K)
    new, moved = ensemble_kalman_step(x, w, d, np.array([np.sqrt(r)]), np.ones((K, 1), bool), rng)
    assert moved.all()
    # the Kalman posterior of a Gaussian prior N(mean(x), var(x)) and one detection
    m0, v0 = x.mean(axis=0)[0], x.var(axis=0)[0]
    gain = v0 / (v0 + r)
    mean, var = m0 + gain * (d[0] - m0), v0 * r / (v0 + r)
    # sample mean within 3 standard errors; sample variance within 3 of its standard deviations
    assert np.all(np.abs(new[:, 0].mean(axis=0) - mean) < 3 * np.sqrt(var / K))
    assert np.all(np.abs(new[:, 0].var(axis=0) - var) < 3 * var * np.sqrt(2 / K))


def test_repeated_steps_converge_to_the_mean_of_the_detections():
    # a static object, its particles drawn 1 cm around a wrong first guess, detected 40 times with
    # 3 mm noise, the filter assuming 1 cm: the cloud's mean follows the Kalman filter of a static
    # position, whose estimate is the average of the prior and the detections
    rng = np.random.default_rng(1)
    K, s_model, s_true, n = 256, 0.01, 0.003, 40
    truth = np.array([0.1, 0.2])
    x = rng.normal(0.0, s_model, (K, 1, 2)) + truth + 0.008
    prior_mean = x.mean(axis=0)[0].copy()
    w = np.full(K, 1.0 / K)
    dets = truth + rng.normal(0.0, s_true, (n, 2))
    for det in dets:
        x, _ = ensemble_kalman_step(x, w, det[None], np.array([s_model]), np.ones((K, 1), bool), rng)
    kf_mean = (prior_mean + dets.sum(axis=0)) / (n + 1)  # equal prior and detection variances
    kf_std = s_model / np.sqrt(n + 1)
    # the ensemble's Monte-Carlo error on its mean is about kf_std / sqrt(K) per step, accumulated
    # over the steps it at most reaches kf_std * sqrt(n / K): 3 of those
    assert np.all(np.abs(x.mean(axis=0)[0] - kf_mean) < 3 * kf_std * np.sqrt(n / K) + 1e-12)
    assert np.all(np.abs(x.std(axis=0)[0] - kf_std) < 0.2 * kf_std)


def test_masked_entries_and_short_steps_stay_and_the_stream_does_not_depend_on_the_mask():
    x = np.zeros((4, 2, 2))
    x[:, 1] = 0.05
    w = np.full(4, 0.25)
    det = np.array([[0.02, 0.0], [0.05, 0.05]])
    mask = np.array([[True, False], [False, True], [True, True], [False, False]])
    a, moved = ensemble_kalman_step(x, w, det, np.array([0.01, 0.01]), mask, np.random.default_rng(3),
                                    floor_std=0.002)
    assert not np.any(moved & ~mask) and np.array_equal(a[~moved], x[~moved])
    b, _ = ensemble_kalman_step(x, w, det, np.array([0.01, 0.01]), np.ones((4, 2), bool), np.random.default_rng(3),
                                floor_std=0.002)
    assert np.array_equal(a[moved], b[moved])  # same draws whatever the mask
    # a step shorter than min_step is not taken
    c, moved_c = ensemble_kalman_step(x, w, det, np.array([0.01, 0.01]), np.ones((4, 2), bool),
                                      np.random.default_rng(3), floor_std=0.002, min_step=1.0)
    assert not moved_c.any() and np.array_equal(c, x)


def test_weighted_variance_and_shape_checks():
    x = np.array([[[0.0]], [[1.0]], [[3.0]]])
    w = np.array([0.5, 0.25, 0.25])
    mean = 0.25 + 0.75
    assert weighted_axis_variance(x, w)[0, 0] == pytest.approx(0.5 * mean**2 + 0.25 * 0 + 0.25 * 4)
    with pytest.raises(ValueError, match="do not agree"):
        ensemble_kalman_step(np.zeros((3, 2, 2)), np.full(3, 1 / 3), np.zeros((2, 3)), np.ones(2),
                             np.ones((3, 2), bool), np.random.default_rng(0))


def test_a_cloud_that_its_target_rejects_moves_whole_and_one_that_it_does_not_stays():
    """The innovation test of each cloud's weighted mean against its target (target standard error
    2 mm, z = 3), along the gap: object 0, every particle at one point (let go at one detection)
    2.2 cm off, moves, in the particles where it may, by the same shift; object 1, a cloud 1 cm
    wide whose mean is 1 cm off, stays (a Kalman step's business); object 2, a cloud 1 mm wide 1 cm
    off, moves and keeps its shape; object 3, one point 4 mm off (2 standard errors), stays; a cloud
    long along x (1 cm) and narrow along y (0.5 mm), 1.5 cm off, stays when the gap is along x
    (object 4) and moves when it is along y (object 5)."""
    rng = np.random.default_rng(3)
    K, N = 400, 6
    x = np.zeros((K, N, 2))
    x[:, 0] = [0.30, 0.20]
    x[:, 1] = np.array([0.10, -0.10]) + rng.normal(0.0, 0.01, (K, 2))
    x[:, 2] = np.array([0.50, 0.00]) + rng.normal(0.0, 0.001, (K, 2))
    x[:, 3] = [0.0, 0.4]
    x[:, 4] = x[:, 5] = np.array([-0.2, 0.0]) + rng.normal(0.0, 1.0, (K, 2)) * [0.01, 0.0005]
    w = rng.uniform(0.5, 1.5, K)
    w /= w.sum()
    mean = np.einsum("k,knd->nd", w, x)
    target = mean + [[0.02, -0.01], [0.01, 0.0], [0.0, 0.01], [0.004, 0.0], [0.015, 0.0], [0.0, 0.015]]
    mask = np.ones((K, N), bool)
    mask[:5, 0] = False  # held there in five particles
    new, moved = shift_inconsistent(x, w, target, np.full(N, 0.002), mask, 3.0)
    assert np.array_equal(moved[:, 0], mask[:, 0]) and moved[:, [2, 5]].all()
    assert not moved[:, [1, 3, 4]].any()
    np.testing.assert_allclose(new[5:, 0], np.broadcast_to(target[0], (K - 5, 2)))
    for j in (2, 5):
        np.testing.assert_allclose(new[:, j] - x[:, j], np.broadcast_to(target[j] - mean[j], (K, 2)), atol=1e-12)
    assert np.array_equal(new[:5, 0], x[:5, 0]) and np.array_equal(new[:, [1, 3, 4]], x[:, [1, 3, 4]])
    with pytest.raises(ValueError, match="shift_inconsistent"):
        shift_inconsistent(x, w, target[:1], np.full(N, 0.002), mask, 3.0)
