"""The log-weight terms, one at a time, on hand-built particle arrays, against answers written out here."""
import math

import numpy as np
import pytest

from actions.modes import FREE, HELD, ModePriors
from estimator.model.likelihood import (
    detection_log_likelihood,
    exploded_log_likelihood,
    hidden_by_person,
    mode_switch_log_prior,
    negative_evidence_log_likelihood,
    orientation_log_likelihood,
    position_log_likelihood,
)
from helpers import gauss3


def yaw(angle):
    return np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)])


DET = np.array([[0.3, -0.2, 0.7]])


def test_position_without_outliers_is_the_gaussian_log_density():
    s = 0.01
    at = DET[None] + 0.0                        # exactly at the detection
    two_sigma = DET[None] + [[0.0, 2 * s, 0.0]]  # 2 sigma away along y
    ll = position_log_likelihood(np.concatenate([at, two_sigma]), DET, np.array([s]), 0.0)
    assert ll.shape == (2, 1) and ll.dtype == np.float64
    assert ll[0, 0] == pytest.approx(math.log(gauss3(0.0, s)), rel=1e-12)
    assert ll[1, 0] == pytest.approx(math.log(gauss3(2 * s, s)), rel=1e-12)
    assert ll[0, 0] - ll[1, 0] == pytest.approx(2.0, rel=1e-12)  # (2 sigma)^2 / 2


def test_position_with_outliers_is_the_mixture_and_a_far_particle_gets_the_floor():
    s, eps = 0.02, 0.05
    pos = DET[None] + np.array([[[0.0, 0.0, 0.0]], [[0.0, 0.0, s]], [[1.0, 0.0, 0.0]]])
    ll = position_log_likelihood(pos, DET, np.array([s]), eps)
    for k, d in enumerate([0.0, s, 1.0]):
        assert ll[k, 0] == pytest.approx(math.log((1 - eps) * gauss3(d, s) + eps), rel=1e-12)
    assert ll[2, 0] == pytest.approx(math.log(eps), abs=1e-12)  # 50 sigma: the outlier floor
    assert position_log_likelihood(pos, DET, np.array([s]), 0.0)[2, 0] < -1000  # no floor without outliers


def test_position_std_is_per_detection():
    dets = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    pos = dets[None] + [[0.0, 0.0, 0.01], [0.0, 0.0, 0.01]]
    ll = position_log_likelihood(pos, dets, np.array([0.01, 0.005]), 0.0)
    assert ll[0, 0] == pytest.approx(math.log(gauss3(0.01, 0.01)))
    assert ll[0, 1] == pytest.approx(math.log(gauss3(0.01, 0.005)))


def test_orientation_term_by_hand_and_sign_invariant():
    s, eps = 0.2, 0.05
    det = yaw(0.3)[None]
    q = np.stack([yaw(0.3), yaw(0.3 + 2 * s), -yaw(0.3 + 2 * s), yaw(0.3 + math.pi)])[:, None]
    lo = orientation_log_likelihood(q, det, s, 0.0)
    assert lo[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert lo[1, 0] == pytest.approx(-2.0, rel=1e-9)  # 2 sigma: -0.5 * 2^2
    assert lo[2, 0] == pytest.approx(lo[1, 0], rel=1e-12)  # q and -q are one rotation
    lo = orientation_log_likelihood(q, det, s, eps)
    assert lo[1, 0] == pytest.approx(math.log((1 - eps) * math.exp(-2.0) + eps), rel=1e-9)
    assert lo[3, 0] == pytest.approx(math.log((1 - eps) * math.exp(-0.5 * (math.pi / s) ** 2) + eps), rel=1e-9)


def test_detection_sums_position_and_orientation_only_where_measured():
    s, so, eps = 0.01, 0.2, 0.1
    det = np.array([[0.0, 0.0, 0.0, *yaw(0.0)], [1.0, 0.0, 0.0, *yaw(1.0)]])
    has_q = np.array([True, False])
    poses = det[None].copy()
    poses[0, 0, :3] += [s, 0.0, 0.0]
    poses[0, 0, 3:] = yaw(so)          # 1 sigma off in angle
    poses[0, 1, 3:] = yaw(2.5)         # not measured: must not count
    ll = detection_log_likelihood(poses, det, has_q, np.array([s, s]), so, eps)
    expect = (math.log((1 - eps) * gauss3(s, s) + eps) + math.log((1 - eps) * math.exp(-0.5) + eps)
              + math.log((1 - eps) * gauss3(0.0, s) + eps))
    assert ll.shape == (1,) and ll[0] == pytest.approx(expect, rel=1e-9)
    no_q = detection_log_likelihood(poses, det, has_q, np.array([s, s]), 0.0, eps)  # orientation_std 0: ignored
    assert no_q[0] == pytest.approx(math.log((1 - eps) * gauss3(s, s) + eps) + math.log((1 - eps) * gauss3(0, s) + eps))


def test_negative_evidence_per_visible_undetected_object():
    miss = 0.1
    visible = np.array([[0.9, 0.0, 0.8],    # objects 0 and 2 in view
                        [0.1, 0.0, 0.0],    # nothing in view (0.1 < threshold)
                        [0.5, 0.9, 0.5]])   # 0 in view; 1 in view but not queried; 2 in view but held
    modes = np.array([[FREE, FREE, FREE], [FREE, FREE, FREE], [FREE, FREE, HELD]], dtype=np.int8)
    queried = np.array([True, False, True])
    in_tracked_hand = np.array([False, False, True])
    ll = negative_evidence_log_likelihood(visible, modes, queried, in_tracked_hand, miss, 0.3)
    assert ll.dtype == np.float64
    assert ll == pytest.approx([2 * math.log(miss), 0.0, math.log(miss)], abs=1e-15)
    # held but its hand is not tracked: it could be seen, it pays
    ll = negative_evidence_log_likelihood(visible, modes, queried, np.zeros(3, bool), miss, 0.3)
    assert ll[2] == pytest.approx(2 * math.log(miss))
    # in a tracked hand but FREE in that particle: it pays too
    ll = negative_evidence_log_likelihood(visible, np.zeros((3, 3), np.int8), queried, in_tracked_hand, miss, 0.3)
    assert ll[2] == pytest.approx(2 * math.log(miss))
    assert np.all(negative_evidence_log_likelihood(visible, modes, np.zeros(3, bool), in_tracked_hand, miss, 0.3) == 0)


def test_hidden_by_person_is_bayes_rule_on_the_sticky_occlusion():
    """P(hidden | n misses in view) = h / (h + (1 - h) miss^n): the prior h at n = 0, rising to 1;
    its complement is what a look at the hand can still find; h = 1 hides always."""
    miss, h = 0.1, 0.25
    n = np.array([[0, 1], [2, 5]])
    p = hidden_by_person(n, h, miss)
    assert p.shape == n.shape and p[0, 0] == pytest.approx(h)
    for k in range(4):
        joint_hidden, joint_seen = h, (1 - h) * miss ** n.flat[k]  # P(hidden, n misses), P(visible, n misses)
        assert p.flat[k] == pytest.approx(joint_hidden / (joint_hidden + joint_seen))
    assert np.all(np.diff(p.ravel()) > 0) and np.all(hidden_by_person(n, 1.0, miss) == 1.0)


def test_mode_switch_prior_values():
    pr = ModePriors(pick=0.02, place=0.2)
    previous = np.array([[FREE, HELD, FREE, HELD]] * 3, dtype=np.int8)
    new = np.array([[HELD, FREE, FREE, HELD],     # Pick, Place, stays free, stays held
                    [FREE, HELD, HELD, FREE],     # stays free, stays held, Pick (unperceived), release (unperceived)
                    [FREE, FREE, FREE, HELD]], dtype=np.int8)
    perceived = np.array([True, True, False, False])
    lp = mode_switch_log_prior(pr, previous, new, perceived)
    assert lp.shape == (3,)
    assert lp[0] == pytest.approx(math.log(0.02) + math.log(0.2))
    assert lp[1] == pytest.approx(math.log(0.98) + math.log(0.8))  # unperceived objects pay nothing
    assert lp[2] == pytest.approx(math.log(0.98) + math.log(0.2))
    assert mode_switch_log_prior(ModePriors(pick=0.0), previous[:1], new[:1], perceived)[0] == -np.inf


def test_exploded_particles_get_minus_infinity():
    out = exploded_log_likelihood(np.array([True, False, True]))
    assert out.dtype == np.float64 and out[0] == 0.0 and out[2] == 0.0 and out[1] == -np.inf


def test_the_acceleration_likelihood_is_a_tempered_gaussian_on_the_entries_weighed():
    """Object 0 is weighed in particles 0 and 1, not in 2 (held there: its physics did not move it),
    which gets the log of their mean likelihood; object 1 is weighed nowhere and adds nothing."""
    from estimator.model.likelihood import acceleration_log_likelihood

    accel = np.array([[[0.5, 0.0], [9.0, 9.0]], [[1.5, 0.1], [0.0, 0.0]], [[np.nan, np.nan], [0.0, 0.0]]])
    seen = np.array([[0.5, 0.0], [0.0, 0.0]])
    std = np.array([0.1, 0.2])
    mask = np.array([[True, False], [True, False], [False, False]])
    out = acceleration_log_likelihood(accel, seen, std, mask, np.array([0.4, 1.0]), 0.0)
    norm = -math.log(2 * math.pi * 0.01)
    own = [norm, norm - 0.5 * (100.0 + 1.0)]
    mean = math.log((math.exp(own[0]) + math.exp(own[1])) / 2)
    assert out == pytest.approx([0.4 * own[0], 0.4 * own[1], 0.4 * mean])
    with_outliers = acceleration_log_likelihood(accel, seen, std, mask, np.ones(2), 0.05)
    assert with_outliers[1] == pytest.approx(math.log(0.05), abs=1e-6)  # a wild one costs an outlier's
