"""Tracked hands: the constant-velocity filter of a hand, the averaged offset of a held object, the
configuration's checks."""
import math

import numpy as np
import pytest

from estimator.config import HandConfig, config_from_dict
from estimator.model.hands import HandFilter, average_offset, filtered_track
from physics.errors import ConfigError


def test_a_hand_that_moves_as_the_model_says_has_the_error_its_covariance_says():
    """300 seeded hands that move as the filter's model does (white acceleration of ``accel_std``,
    a starting velocity of 1 m/s standard deviation per axis), seen 1 cm off per axis at 30
    frames/s for 1 s: the normalised error (x - truth)^T P^-1 (x - truth) of the position averages
    3 (its chi-square mean) within 3 standard errors."""
    from estimator.model.hands import process_noise, transition
    cfg = HandConfig(measurement_std=0.01)
    rng = np.random.default_rng(11)
    f, q = transition(1 / 30), process_noise(1 / 30, cfg.accel_std)
    nees = []
    for _ in range(300):
        hand = HandFilter(cfg)
        x = np.concatenate([[0.2, -0.1, 1.0], rng.normal(0.0, 1.0, 3)])
        for k in range(30):
            if k:
                x = f @ x + rng.multivariate_normal(np.zeros(6), q)
            hand.update(k / 30, x[:3] + rng.normal(0.0, 0.01, 3))
        e = hand.position - x[:3]
        nees.append(e @ np.linalg.solve(hand.P[:3, :3], e))
    assert abs(np.mean(nees) - 3.0) < 3 * math.sqrt(2 * 3 / 300)


def test_process_noise_is_filterpys_white_acceleration_value_for_value():
    """The hands' process noise, written here so that the estimator does not import filterpy, is
    filterpy's Q_discrete_white_noise (order [x, y, z, vx, vy, vz]) exactly."""
    from filterpy.common import Q_discrete_white_noise

    from estimator.model.hands import process_noise
    for dt in (1 / 30, 0.08, 0.1, 2.0):
        for accel_std in (0.5, 3.0, 7.3):
            assert np.array_equal(process_noise(dt, accel_std), Q_discrete_white_noise(
                dim=2, dt=dt, var=accel_std ** 2, block_size=3, order_by_dim=False))


def test_a_still_hand_is_known_better_than_from_one_frame():
    """A still hand seen 1 cm off per axis for 1 s (300 seeded runs): the filtered position's RMS
    error per axis is under 0.8 cm (the model's white acceleration keeps it from averaging all 30
    frames, which would give 0.18 cm)."""
    rng = np.random.default_rng(12)
    truth = np.array([0.2, -0.1, 1.0])
    err2 = []
    for _ in range(300):
        hand = HandFilter(HandConfig(measurement_std=0.01))
        for k in range(30):
            hand.update(k / 30, truth + rng.normal(0.0, 0.01, 3))
        err2.append(np.sum((hand.position - truth) ** 2) / 3)
    assert math.sqrt(np.mean(err2)) < 0.008


def test_uniform_motion_is_followed_without_lag_once_caught_up():
    """Exact positions of a hand moving at 0.5 m/s: after a second the filter is on it and has
    its velocity; a stop is followed within 2 cm at any frame and exactly a second later."""
    hand = HandFilter(HandConfig())
    v = np.array([0.5, 0.0, -0.1])
    for k in range(31):
        hand.update(k / 30, v * k / 30)
    np.testing.assert_allclose(hand.position, v, atol=1e-4)
    np.testing.assert_allclose(hand.velocity, v, atol=1e-3)
    worst = 0.0
    for k in range(31, 62):
        worst = max(worst, float(np.linalg.norm(hand.update(k / 30, v) - v)))
    assert worst < 0.02
    np.testing.assert_allclose(hand.position, v, atol=1e-3)


def test_a_hand_back_after_a_gap_starts_again_and_unfiltered_is_raw():
    cfg = HandConfig(restart_gap=0.5)
    hand = HandFilter(cfg)
    assert np.all(np.isnan(hand.position))
    hand.update(0.0, [0.0, 0.0, 1.0])
    hand.update(1.0, [0.4, 0.0, 1.0])  # a second later: not a jump to filter
    np.testing.assert_allclose(hand.position, [0.4, 0.0, 1.0])
    np.testing.assert_allclose(hand.velocity, 0.0)
    raw = HandFilter(HandConfig(filtered=False))
    raw.update(0.0, [0.0, 0.0, 1.0])
    raw.update(1 / 30, [0.01, 0.0, 1.0])
    np.testing.assert_allclose(raw.position, [0.01, 0.0, 1.0])


def test_filtered_track_skips_the_frames_without_the_hand():
    times = np.arange(5) / 30
    pos = np.array([[0, 0, 1.0], [np.nan] * 3, [0, 0, 1.0], [0, 0, 1.0], [np.nan] * 3])
    out = filtered_track(times, pos, HandConfig())
    assert np.all(np.isnan(out[[1, 4]])) and np.allclose(out[[0, 2, 3]], [0, 0, 1.0])


def test_average_offset_weights_gate_and_start():
    cfg = HandConfig(offset_time=0.5, offset_gate=0.04)
    m, n = average_offset(np.zeros(3), 0, math.inf, [0.0, 0.0, -0.1], cfg)
    assert n == 1 and np.allclose(m, [0.0, 0.0, -0.1])
    m2, n2 = average_offset(m, n, 1 / 30, [0.0, 0.02, -0.1], cfg)  # second frame: weight 1/2
    assert n2 == 2 and np.allclose(m2, [0.0, 0.01, -0.1])
    a = 1.0 - math.exp(-(1 / 30) / 0.5)  # after many frames: the exponential weight
    m3, _ = average_offset(m2, 100, 1 / 30, [0.0, 0.02, -0.1], cfg)
    assert np.allclose(m3, m2 + a * (np.array([0.0, 0.02, -0.1]) - m2))
    far, n4 = average_offset(m2, 100, 1 / 30, [0.05, 0.0, -0.1], cfg)  # beyond the gate: a new grasp
    assert n4 == 1 and np.allclose(far, [0.05, 0.0, -0.1])
    last, _ = average_offset(m2, 100, 1 / 30, [0.0, 0.02, -0.1], HandConfig(filtered=False))
    assert np.allclose(last, [0.0, 0.02, -0.1])


def test_hand_configuration_is_checked_and_read_from_configuration_data():
    with pytest.raises(ValueError, match="measurement_std"):
        HandConfig(measurement_std=0.0)
    with pytest.raises(ValueError, match="filtered"):
        HandConfig(filtered="yes")
    cfg = config_from_dict({"hands": {"measurement_std": 0.02, "filtered": False}}, particles=8)
    assert cfg.hands == HandConfig(measurement_std=0.02, filtered=False)
    with pytest.raises(ConfigError, match="hands.offset_gate"):
        config_from_dict({"hands": {"offset_gate": -1.0}}, path="c.yaml")
