"""The tracker's position noise measured from the scatter of detections about their fitted lines."""
import math

import numpy as np
import pytest

from estimator.model.detection_noise import ONSET_FALSE_ALARM, ONSET_SIGMAS, DetectionNoise, onset_distance


def _scatters(rng, sigma, n_points, count):
    """Scatters (RMS per axis over 2 (n - 2) degrees of freedom) of ``count`` lines fitted to
    ``n_points`` detections of two axes with Gaussian noise ``sigma``."""
    t = np.arange(n_points) - (n_points - 1) / 2
    out = []
    for _ in range(count):
        xy = rng.normal(0.0, sigma, (n_points, 2))
        slope = t @ (xy - xy.mean(axis=0)) / (t @ t)
        resid = xy - xy.mean(axis=0) - t[:, None] * slope
        out.append(math.sqrt(float(np.sum(resid ** 2)) / (2 * (n_points - 2))))
    return out


def test_noise_alone_passes_the_onset_distance_at_the_stated_false_alarm_rate():
    # three Gaussian axes of unit noise: the distance passes ONSET_SIGMAS once in 1 / ONSET_FALSE_ALARM
    rng = np.random.default_rng(5)
    n = 400_000
    beyond = np.mean(np.linalg.norm(rng.normal(0.0, 1.0, (n, 3)), axis=1) > ONSET_SIGMAS)
    assert abs(beyond - ONSET_FALSE_ALARM) < 3 * math.sqrt(ONSET_FALSE_ALARM * (1 - ONSET_FALSE_ALARM) / n)


def test_onset_distance_never_under_its_floor_and_floor_until_measured():
    assert onset_distance(math.nan, 0.015) == 0.015
    assert onset_distance(0.003, 0.015) == 0.015  # a 3 mm tracker: 1.2 cm, under the floor
    assert onset_distance(0.01, 0.015) == pytest.approx(ONSET_SIGMAS * 0.01)


@pytest.mark.parametrize("sigma", [0.003, 0.01])
def test_the_estimate_is_the_noise_within_its_sampling_band(sigma):
    rng = np.random.default_rng(7)
    noise = DetectionNoise(window=64, min_samples=8)
    assert math.isnan(noise.std)
    estimates = []
    for s in _scatters(rng, sigma, 6, 64 * 40):
        noise.add(s, 8)
        if len(noise) == 64:
            estimates.append(noise.std)
    est = np.array(estimates[::64])  # disjoint windows: independent medians
    # the median of 64 variances scaled chi-square(8)/8 has a relative standard deviation of about
    # sqrt(pi/2) * sqrt(2/8) / sqrt(64) = 0.078 in variance, half that in std; the mean of 40
    # windows is within 3 of its standard errors
    assert abs(est.mean() / sigma - 1.0) < 3 * 0.039 / math.sqrt(len(est)) + 0.01
    assert np.all(np.abs(est / sigma - 1.0) < 4 * 0.039 + 0.01)


def test_a_third_of_objects_accelerating_does_not_move_the_estimate_far():
    rng = np.random.default_rng(9)
    noise = DetectionNoise(window=64, min_samples=8)
    still = _scatters(rng, 0.01, 6, 64)
    for i, s in enumerate(still):
        noise.add(s * 10.0 if i % 3 == 0 else s, 8)  # every third: a curve's scatter, ten times
    # the median then sits at the 75th percentile of the still ones: within 30 % of the noise
    assert 0.9 < noise.std / 0.01 < 1.3


def test_bad_samples_are_ignored_and_bad_windows_refused():
    noise = DetectionNoise(window=4, min_samples=1)
    noise.add(math.nan, 8)
    noise.add(0.01, 0)
    assert len(noise) == 0 and math.isnan(noise.std)
    with pytest.raises(ValueError):
        DetectionNoise(window=4, min_samples=5)
