"""estimator.model.tracks: the line, the free fall and the rest of one object's detections."""
import math

import numpy as np
import pytest

from estimator.model.tracks import dwell_back, fit_acceleration, fit_line, free_fall, rested


def _history(times, positions, orientation=None):
    return [(float(t), tuple(map(float, p)), orientation) for t, p in zip(times, positions)]


def test_a_line_through_noisy_detections_recovers_the_velocity_within_its_standard_error():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 0.2, 1 / 30)
    sigma, v = 0.003, np.array([0.5, -0.2, 0.0])
    errors = []
    for _ in range(200):
        pos = np.array([0.1, 0.2, 0.7]) + v * t[:, None] + rng.normal(0, sigma, (len(t), 3))
        slope, sxx, at, scatter, dof = fit_line(_history(t, pos), -math.inf, t[-1])
        errors.append((slope[:2] - v[:2]) / (sigma / math.sqrt(sxx)))
        assert dof == 2 * (len(t) - 2)
    z = np.array(errors)
    # standardised slope errors: mean 0, variance 1 (400 draws: 3 standard errors of each)
    assert abs(z.mean()) < 3 / math.sqrt(z.size) and abs(z.var() - 1) < 3 * math.sqrt(2 / z.size)
    exact = np.array([0.1, 0.2, 0.7]) + v * t[:, None]
    slope, _, at, scatter, _ = fit_line(_history(t, exact), -math.inf, t[-1])
    assert np.allclose(slope, v) and np.allclose(at, exact[-1, :2]) and scatter < 1e-12
    assert fit_line(_history(t[:1], exact[:1]), -math.inf, t[0])[4] == 0  # one detection: no line


def test_the_free_fall_through_the_last_two_detections_is_the_analytic_one():
    g, z0, t = 9.81, 1.0, np.array([0.0, 0.1, 0.2])
    heights = z0 - 0.5 * g * t ** 2
    hist = _history(t, [[0, 0, h] for h in heights])
    z, vz, err = free_fall(hist, 0.0, np.array([0.2, 0.3, -0.1]), g, 0.002)
    assert np.allclose(z[:2], z0 - 0.5 * g * np.array([0.2, 0.3]) ** 2) and np.allclose(vz[:2], [-g * 0.2, -g * 0.3])
    assert math.isclose(z[2], z0) and vz[2] == 0.0  # before it began: at rest at the top
    assert math.isclose(err, math.sqrt(2) * 0.002 / 0.1)
    assert free_fall(_history(t, [[0, 0, 1.0 + s] for s in t]), 0.0, t, g, 0.002) is None  # rising: not falling
    assert free_fall(hist, 0.15, t, g, 0.002) is None  # one detection in the segment


def test_detections_rest_when_they_moved_and_turned_less_than_the_rule_allows():
    t = np.arange(0.0, 0.5, 1 / 30)
    still = _history(t, [[0.0, 0.0, 0.7]] * len(t))
    assert rested(still, t[-1], 0.2, 0.05, 0.5) and not rested(still, t[-1] + 0.3, 0.2, 0.05, 0.5)
    sliding = _history(t, [[0.2 * s, 0.0, 0.7] for s in t])  # 0.2 m/s
    assert not rested(sliding, t[-1], 0.2, 0.05, 0.5) and rested(sliding, t[-1], 0.2, 0.5, 0.5)
    assert not rested(still, t[-1], 0.2, 0.05, 0.5, distance=0.0)
    assert dwell_back(still, t[-1], 0.2)[0] <= t[-1] - 0.2 + 1e-9 and dwell_back(still[:2], t[1], 0.2) is None


def test_a_parabola_through_noisy_detections_recovers_the_deceleration_within_its_standard_error():
    """A ball slowing down at 0.6 m/s^2 along x from 1 m/s, seen at 30 Hz with 3 mm of noise per
    axis for 0.8 s: over 400 draws the standard error the fit states is the spread it has (the
    error within 1.96 of them in 95 % of draws, inside a binomial band of 3 standard deviations),
    and it is small enough to tell a rolling friction from twice it (about 0.3 m/s^2 apart)."""
    rng = np.random.default_rng(12)
    t = np.arange(0.0, 0.8 + 1e-9, 1 / 30)
    truth = np.stack([1.0 * t - 0.3 * t * t, 0.02 * t, np.full_like(t, 0.655)], axis=1)
    inside, ses = 0, []
    for _ in range(400):
        fit = fit_acceleration(_history(t, truth + rng.normal(0.0, 0.003, truth.shape)), 0.0, t[-1], 0.003)
        a, se, span = fit
        inside += int(abs(a[0] + 0.6) < 1.96 * se and abs(a[1]) < 1.96 * se)
        ses.append(se)
    p, n = 0.95 ** 2, 400  # both axes inside
    assert abs(inside / n - p) < 3 * math.sqrt(p * (1 - p) / n)
    assert span == pytest.approx(0.8) and max(ses) < 0.1 and np.ptp(ses) < 1e-12


def test_no_deceleration_from_too_few_detections_or_too_short_a_span():
    t = np.arange(0.0, 0.3, 1 / 30)
    hist = _history(t, np.stack([t, 0 * t, 0 * t], axis=1))
    assert fit_acceleration(hist[:4], 0.0, 1.0, 0.003) is None  # four detections
    assert fit_acceleration(hist, 0.2, 1.0, 0.003) is None  # from 0.2 s: 0.1 s of them
    a, se, span = fit_acceleration(hist, 0.0, 1.0, 0.003)
    assert np.allclose(a, 0.0, atol=1e-9) and se > 0
