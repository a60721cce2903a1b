"""estimator.model.terms: the log-weight terms as objects, on hand-built evidence."""
import math
from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD, ModePriors
from estimator.model.likelihood import (
    hand_reach_log_likelihood,
    negative_evidence_log_likelihood,
)
from estimator.model.terms import (
    DetectionTerm,
    Evidence,
    HandReachTerm,
    ModeSwitchTerm,
    NegativeEvidenceTerm,
    add_terms,
    held_unseen_in_view,
)
from helpers import gauss3

DET = np.array([[0.3, -0.2, 0.7]])


def _evidence(K=2, M=2):
    """Nothing detected, nothing queried, everything FREE and finite; tests replace fields."""
    return Evidence(poses=np.zeros((K, M, 7)), predicted=np.zeros((K, M, 7)),
                    previous_modes=np.zeros((K, M), np.int8), modes=np.zeros((K, M), np.int8),
                    detected=np.zeros(M, bool), teleported=np.zeros(M, bool), perceived=np.zeros(M, bool),
                    detected_poses=np.zeros((M, 7)), has_orientation=np.zeros(M, bool),
                    detection_std=np.full(M, np.nan), visible=np.zeros((K, M)), queried=np.zeros(M, bool),
                    in_tracked_hand=np.zeros(M, bool), finite=np.ones(K, bool),
                    unseen_in_view=np.zeros((K, M), np.int32))


def test_hand_occlusion_is_sticky_and_its_total_cost_is_bounded_by_h():
    """Held in a tracked hand and in view, undetected for n updates: the increments add up to
    log(h + (1 - h) miss^n) exactly, so the total never falls below log(h); a free object pays
    log(miss) every time; h = 1 exempts held objects."""
    miss, h = 0.1, 0.25
    visible = np.array([[1.0, 1.0], [1.0, 0.0]])
    modes = np.array([[HELD, FREE], [HELD, HELD]], np.int8)
    queried, hand = np.array([True, True]), np.array([True, True])
    ev = replace(_evidence(), visible=visible, modes=modes, queried=queried, in_tracked_hand=hand)
    total = np.zeros(2)
    for n in range(6):
        total += negative_evidence_log_likelihood(visible, modes, queried, hand, miss, 0.5, h, ev.unseen_in_view)
        counts = held_unseen_in_view(ev, 0.5)
        assert counts[0, 0] == n + 1 and counts[0, 1] == 0 and counts[1, 1] == 0  # free / out of view
        ev = replace(ev, unseen_in_view=counts)
        expect0 = math.log(h + (1 - h) * miss ** (n + 1)) + (n + 1) * math.log(miss)
        expect1 = math.log(h + (1 - h) * miss ** (n + 1))
        assert total[0] == pytest.approx(expect0) and total[1] == pytest.approx(expect1)
    assert total[1] > math.log(h) - 1e-12
    exempt = negative_evidence_log_likelihood(visible, modes, queried, hand, miss, 0.5, 1.0, ev.unseen_in_view)
    assert exempt[0] == pytest.approx(math.log(miss)) and exempt[1] == 0.0
    # a detection resets the count
    assert np.all(held_unseen_in_view(replace(ev, detected=np.array([True, True])), 0.5) == 0)


def test_only_a_carried_object_gets_the_person_allowance_a_still_hands_pays_every_miss():
    """Two objects held in tracked hands, both in view and undetected for n updates: the first one's
    hand carried it away since it was last seen (``Evidence.carried``), the second one's stayed put.
    The first is bounded by log h in all (the person may hide what they carry); the second pays
    log(miss) at every update, as a free object does: a hand that did not move can hide its object
    only with itself, which the visible fraction already says. With ``carried`` None every held
    object gets the allowance (the old reading)."""
    miss, h = 0.1, 0.25
    term = NegativeEvidenceTerm(miss, 0.5, h)
    ev = replace(_evidence(K=1, M=2), visible=np.ones((1, 2)), modes=np.array([[HELD, HELD]], np.int8),
                 queried=np.array([True, True]), in_tracked_hand=np.array([True, True]),
                 carried=np.array([True, False]))
    total, both = np.zeros(1), np.zeros(1)
    for n in range(5):
        total += term(ev)
        both += term(replace(ev, carried=None))
        ev = replace(ev, unseen_in_view=held_unseen_in_view(ev, 0.5))
    assert total[0] == pytest.approx(math.log(h + (1 - h) * miss ** 5) + 5 * math.log(miss))
    assert both[0] == pytest.approx(2 * math.log(h + (1 - h) * miss ** 5))
    assert NegativeEvidenceTerm(miss, 0.5, 1.0)(ev)[0] == 0.0  # paper mode: held objects exempt


def test_detection_term_scores_a_teleported_object_where_the_particle_predicted_it():
    poses = np.zeros((2, 2, 7))
    predicted = np.zeros((2, 2, 7))
    predicted[1, 0, :3] = [0.02, 0.0, 0.0]  # particle 1 expected object 0 2 cm away; it was then teleported
    poses[:, 1, :3] = [0.0, 0.0, 0.01]      # object 1 not teleported: scored where it is
    ev = replace(_evidence(), poses=poses, predicted=predicted, detected=np.array([True, True]),
                 teleported=np.array([True, False]), detection_std=np.array([np.nan, 0.005]))
    term = DetectionTerm(default_std=0.01, orientation_std=0.0, outlier_prob=0.0)
    ll = term(ev)
    d0 = [math.log(gauss3(0.0, 0.01)), math.log(gauss3(0.02, 0.01))]  # no std given: the default 0.01
    d1 = math.log(gauss3(0.01, 0.005))
    assert ll == pytest.approx([d0[0] + d1, d0[1] + d1], rel=1e-12)
    assert np.all(term(_evidence()) == 0)  # nothing detected: no information
    tiny = DetectionTerm(default_std=0.0, orientation_std=0.0, outlier_prob=0.0)(ev)  # floored at 1 mm
    assert tiny[1] - tiny[0] == pytest.approx(-0.5 * 0.02 ** 2 / 0.001 ** 2)


def test_detection_term_scores_an_object_physics_let_diverge_at_its_divergence_not_where_it_was_put():
    # both particles' object ends on its detection; particle 1's physics had let it diverge by 5 cm
    # first (the world then put it on the perception): it is scored 5 cm away, with the orientation
    # it expected, not rewarded for the override
    det = np.array([[0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0]])
    poses = np.broadcast_to(det, (2, 1, 7)).copy()
    predicted = poses.copy()
    predicted[1, 0, 3:] = [0.0, 0.0, math.sin(0.05), math.cos(0.05)]  # 0.1 rad about z
    ev = replace(_evidence(K=2, M=1), poses=poses, predicted=predicted, detected=np.array([True]),
                 detected_poses=det, has_orientation=np.array([True]), detection_std=np.array([0.01]),
                 diverged=np.array([[np.nan], [0.05]]))
    ll = DetectionTerm(default_std=0.01, orientation_std=0.1, outlier_prob=0.0)(ev)
    assert ll[0] == pytest.approx(math.log(gauss3(0.0, 0.01)), rel=1e-12)
    assert ll[1] == pytest.approx(math.log(gauss3(0.05, 0.01)) - 0.5 * (0.1 / 0.1) ** 2, rel=1e-9)
    same = DetectionTerm(default_std=0.01, orientation_std=0.1, outlier_prob=0.0)(replace(ev, diverged=None))
    assert same[1] == pytest.approx(same[0])  # without the field, the override would look perfect


def test_an_object_that_fell_off_its_support_is_weighed_on_its_horizontal_position_only():
    """Three particles of a ball seen falling, free after the update: 3 cm low, 3 cm high, and 1 cm
    off horizontally. Marked as fallen (``fell``), the first two match the detection exactly and the
    third pays its 1 cm; unmarked, or still held in a particle (held in the air), the heights count."""
    det = np.array([[0.1, 0.2, 0.6, 0.0, 0.0, 0.0, 1.0]])
    poses = np.broadcast_to(det, (3, 1, 7)).copy()
    poses[0, 0, 2] -= 0.03
    poses[1, 0, 2] += 0.03
    poses[2, 0, 0] += 0.01
    ev = replace(_evidence(K=3, M=1), poses=poses, predicted=poses.copy(), detected=np.array([True]),
                 detected_poses=det, has_orientation=np.array([False]), detection_std=np.array([0.01]),
                 fell=np.array([True]))
    term = DetectionTerm(default_std=0.01, orientation_std=0.1, outlier_prob=0.0)
    ll = term(ev)
    assert ll[0] == pytest.approx(math.log(gauss3(0.0, 0.01)), rel=1e-12) and ll[1] == pytest.approx(ll[0])
    assert ll[2] == pytest.approx(math.log(gauss3(0.01, 0.01)), rel=1e-12)
    plain = term(replace(ev, fell=None))
    assert plain[0] == pytest.approx(math.log(gauss3(0.03, 0.01)), rel=1e-12) and plain[2] == pytest.approx(ll[2])
    assert term(replace(ev, fell=np.array([False]))) == pytest.approx(plain)
    held = term(replace(ev, modes=np.array([[FREE], [HELD], [FREE]], np.int8)))
    assert held[0] == pytest.approx(ll[0]) and held[1] == pytest.approx(plain[1])


def test_terms_are_added_in_order_to_the_previous_log_weights():
    visible = np.array([[1.0, 0.0], [1.0, 1.0]])
    ev = replace(_evidence(), visible=visible, queried=np.array([True, True]), perceived=np.array([True, False]),
                 modes=np.array([[HELD, FREE], [FREE, FREE]], np.int8))
    terms = (NegativeEvidenceTerm(miss_prob=0.5, visibility_threshold=0.3), ModeSwitchTerm(ModePriors(pick=0.1)))
    out = add_terms(np.array([0.0, -1.0]), terms, ev)
    assert out == pytest.approx([math.log(0.5) + math.log(0.1), -1.0 + 2 * math.log(0.5) + math.log(0.9)])
    prev = np.array([0.0, -1.0])
    add_terms(prev, terms, ev)
    assert list(prev) == [0.0, -1.0]  # not modified in place


def test_hand_reach_charges_each_held_object_seen_out_of_reach_and_nothing_else():
    modes = np.array([[HELD, HELD, FREE], [FREE, HELD, HELD], [FREE, FREE, FREE]], np.int8)
    far = np.array([True, False, True])  # objects 0 and 2 detected out of reach of every tracked hand
    ll = hand_reach_log_likelihood(modes, far, 0.01)
    assert ll == pytest.approx([math.log(0.01), math.log(0.01), 0.0])
    two = hand_reach_log_likelihood(np.array([[HELD, FREE, HELD]], np.int8), far, 0.01)
    assert two == pytest.approx([2 * math.log(0.01)])
    assert hand_reach_log_likelihood(modes, far, 0.0)[0] == -np.inf  # impossible: zero weight
    assert np.all(hand_reach_log_likelihood(modes, np.zeros(3, bool), 0.01) == 0)
    ev = replace(_evidence(), modes=np.array([[HELD, FREE], [FREE, FREE]], np.int8))
    assert np.all(HandReachTerm(0.01)(ev) == 0)  # no hand tracked: out_of_reach is None
    ev = replace(ev, out_of_reach=np.array([True, False]))
    assert HandReachTerm(0.01)(ev) == pytest.approx([math.log(0.01), 0.0])
