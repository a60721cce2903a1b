"""Metrics of experiments.evaluation.metrics on hand-made inputs with known answers."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal, multivariate_t

from experiments.evaluation import metrics as M


# -- positions ---------------------------------------------------------------------------------------
def test_position_error_is_zero_for_a_perfect_estimate_and_euclidean_otherwise():
    truth = np.array([[[0.1, 0.2, 0.7], [1.0, -1.0, 0.0]]])
    assert np.all(M.position_errors(truth, truth) == 0.0)
    est = truth + np.array([0.03, 0.04, 0.0])
    np.testing.assert_allclose(M.position_errors(est, truth), 0.05)
    assert np.isnan(M.position_errors(np.full(3, np.nan), np.zeros(3)))


def test_error_quantiles_select_by_mask_and_skip_nan():
    e = np.array([[0.01, 0.02], [0.03, np.nan], [0.10, 0.04]])
    hidden = np.array([[True, False], [True, True], [True, False]])
    q = M.error_quantiles(e, hidden)
    assert q["n"] == 3
    assert q["median"] == pytest.approx(0.03)
    assert q["p90"] == pytest.approx(np.percentile([0.01, 0.03, 0.10], 90))
    empty = M.error_quantiles(e, np.zeros_like(hidden))
    assert empty["n"] == 0 and math.isnan(empty["median"]) and math.isnan(empty["p90"])


def test_hidden_durations_count_from_the_last_visible_step_or_the_first_step():
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    vis = np.array([[True, False], [False, False], [False, True], [True, False], [False, False]])
    d = M.hidden_durations(t, vis)
    # object 0: seen at 0, hidden 0.1 and 0.2 later, seen at 0.3, hidden 0.1 later
    np.testing.assert_allclose(d[:, 0], [0.0, 0.1, 0.2, 0.0, 0.1])
    # object 1: hidden from the first step (counted from it), seen at 0.2, then hidden
    np.testing.assert_allclose(d[:, 1], [0.0, 0.1, 0.0, 0.1, 0.2])
    assert M.hidden_durations(np.zeros(0), np.zeros((0, 3), bool)).shape == (0, 3)
    with pytest.raises(ValueError, match="do not agree"):
        M.hidden_durations(t[:4], vis)


def test_truth_support_priority_isin_then_isontop_then_held_then_none():
    rels = [{"subject": "ball", "predicate": "isOnTop", "object": "table", "p": 1.0},
            {"subject": "ball", "predicate": "isIn", "object": "box", "p": 1.0},
            {"subject": "cup", "predicate": "isOnTop", "object": "table", "p": 1.0},
            {"subject": "cup", "predicate": "isOnTop", "object": "book", "p": 1.0}]
    assert M.truth_supports(rels, "ball", held=True) == {("isIn", "box")}
    assert M.truth_supports(rels, "cup", held=False) == {("isOnTop", "table"), ("isOnTop", "book")}
    assert M.truth_supports(rels, "mug", held=True) == {("held", None)}
    assert M.truth_supports(rels, "mug", held=False) == {("none", None)}


def test_success_needs_small_error_and_the_right_support():
    sup = {("isIn", "box")}
    assert M.success(0.0, ("isIn", "box"), sup)
    assert M.success(0.049, ("isIn", "box"), sup)
    assert not M.success(0.05, ("isIn", "box"), sup)
    assert not M.success(0.01, ("isOnTop", "table"), sup)
    assert not M.success(float("nan"), ("isIn", "box"), sup)


# -- binary facts ------------------------------------------------------------------------------------
def test_binary_scores_perfect_and_known_counts():
    y = np.array([1, 0, 1, 0, 0, 1], bool)
    perfect = M.binary_scores(y, y)
    assert perfect["f1"] == 1.0 and perfect["accuracy"] == 1.0
    assert perfect["precision"] == 1.0 and perfect["recall"] == 1.0
    p = np.array([1, 1, 0, 0, 0, 1], bool)  # tp 2, fp 1, fn 1, tn 2
    s = M.binary_scores(p, y)
    assert s["precision"] == pytest.approx(2 / 3)
    assert s["recall"] == pytest.approx(2 / 3)
    assert s["f1"] == pytest.approx(2 / 3)
    assert s["accuracy"] == pytest.approx(4 / 6)


def test_binary_scores_empty_conventions():
    none = np.zeros(4, bool)
    both_empty = M.binary_scores(none, none)
    assert math.isnan(both_empty["f1"]) and both_empty["accuracy"] == 1.0
    missed = M.binary_scores(none, np.array([1, 0, 0, 0], bool))
    assert missed["f1"] == 0.0 and missed["recall"] == 0.0 and math.isnan(missed["precision"])
    false_alarm = M.binary_scores(np.array([1, 0, 0, 0], bool), none)
    assert false_alarm["f1"] == 0.0 and false_alarm["precision"] == 0.0 and math.isnan(false_alarm["recall"])


# -- events ------------------------------------------------------------------------------------------
TRUE_EVENTS = [{"t": 1.0, "action": "Pick", "subject": "cup"},
               {"t": 2.0, "action": "Place", "subject": "cup"},
               {"t": 3.0, "action": "Release", "subject": "ball"}]


def test_perfect_events_score_f1_one_and_zero_latency():
    s = M.event_scores(TRUE_EVENTS, TRUE_EVENTS)
    assert s["f1"] == 1.0 and s["precision"] == 1.0 and s["recall"] == 1.0
    assert s["latency_median"] == 0.0 and s["n_matched"] == 3


def test_event_matching_window_subject_action_and_latency_sign():
    est = [{"t": 1.3, "action": "Pick", "subject": "cup"},        # 0.3 s late: matched
           {"t": 2.7, "action": "Place", "subject": "cup"},       # 0.7 s late: outside the window
           {"t": 2.9, "action": "Release", "subject": "cup"}]     # wrong subject
    s = M.event_scores(est, TRUE_EVENTS)
    assert s["n_matched"] == 1
    assert s["precision"] == pytest.approx(1 / 3) and s["recall"] == pytest.approx(1 / 3)
    assert s["f1"] == pytest.approx(1 / 3)
    assert s["latency_median"] == pytest.approx(0.3)
    early = M.event_scores([{"t": 0.8, "action": "Pick", "subject": "cup"}], TRUE_EVENTS[:1])
    assert early["latency_median"] == pytest.approx(-0.2)
    wide = M.event_scores(est, TRUE_EVENTS, window=1.0)
    assert wide["n_matched"] == 2


def test_event_matching_is_one_to_one_and_greedy_by_distance():
    truth = [{"t": 1.0, "action": "Pick", "subject": "cup"}, {"t": 1.4, "action": "Pick", "subject": "cup"}]
    est = [{"t": 1.35, "action": "Pick", "subject": "cup"}, {"t": 1.05, "action": "Pick", "subject": "cup"},
           {"t": 1.2, "action": "Pick", "subject": "cup"}]
    assert M.match_events(est, truth) == [(0, 1), (1, 0)]  # the closest pairs; the third is spare
    s = M.event_scores(est, truth)
    assert s["precision"] == pytest.approx(2 / 3) and s["recall"] == 1.0


def test_event_scores_empty_and_per_action():
    both = M.event_scores([], [])
    assert math.isnan(both["f1"]) and math.isnan(both["latency_median"])
    missed = M.event_scores([], TRUE_EVENTS)
    assert missed["f1"] == 0.0 and missed["recall"] == 0.0
    picks = M.event_scores(TRUE_EVENTS[:1], TRUE_EVENTS, actions=("Pick",))
    assert picks["f1"] == 1.0 and picks["n_true"] == 1


def test_event_scores_by_action_score_each_of_the_four_actions_alone():
    truth = TRUE_EVENTS + [{"t": 4.0, "action": "Push", "subject": "box"}]
    est = [{"t": 1.2, "action": "Pick", "subject": "cup"},      # matched, 0.2 s late
           {"t": 2.1, "action": "Place", "subject": "cup"},     # matched, 0.1 s late
           {"t": 3.9, "action": "Pick", "subject": "box"},      # a push read as a Pick: false Pick...
           {"t": 4.8, "action": "Place", "subject": "box"}]     # ...and false Place; Release missed
    by = M.event_scores_by_action(est, truth)
    assert list(by) == ["Pick", "Place", "Release", "Push"] == list(M.ACTIONS)
    assert by["Pick"]["precision"] == 0.5 and by["Pick"]["recall"] == 1.0
    assert by["Pick"]["f1"] == pytest.approx(2 / 3) and by["Pick"]["latency_median"] == pytest.approx(0.2)
    assert by["Place"]["n_matched"] == 1 and by["Place"]["latency_median"] == pytest.approx(0.1)
    assert by["Release"]["f1"] == 0.0 and by["Release"]["recall"] == 0.0 and math.isnan(by["Release"]["precision"])
    assert by["Push"]["f1"] == 0.0 and by["Push"]["n_true"] == 1 and by["Push"]["n_est"] == 0
    pushed = M.event_scores_by_action([{"t": 4.3, "action": "Push", "subject": "box"}], truth)["Push"]
    assert pushed["f1"] == 1.0 and pushed["latency_median"] == pytest.approx(0.3)
    # an action absent from both lists is undefined, not perfect
    none = M.event_scores_by_action([], [])["Push"]
    assert math.isnan(none["f1"]) and none["n_true"] == 0


# -- calibration -------------------------------------------------------------------------------------
def test_gaussian_nll_matches_scipy_with_the_floor():
    mean = np.array([0.1, 0.2, 0.7])
    cov = np.array([[4e-4, 1e-4, 0], [1e-4, 9e-4, 0], [0, 0, 1e-4]])
    x = np.array([0.12, 0.17, 0.71])
    floor = M.COV_FLOOR_STD ** 2 * np.eye(3)
    expected = -multivariate_normal(mean, cov + floor).logpdf(x)
    assert M.gaussian_nll(mean, cov, x) == pytest.approx(expected, rel=1e-10)
    # a point estimate falls back on the floor alone; a perfect one has the floor's peak density
    peak = -multivariate_normal(np.zeros(3), floor).logpdf(np.zeros(3))
    assert M.gaussian_nll(np.zeros(3), np.zeros((3, 3)), np.zeros(3)) == pytest.approx(peak)
    batch = M.gaussian_nll(np.stack([mean, mean]), np.stack([cov, cov]), np.stack([x, mean]))
    assert batch.shape == (2,) and batch[1] < batch[0]


def test_coverage_of_a_calibrated_gaussian_is_its_level():
    rng = np.random.default_rng(7)
    n = 20000
    cov = np.diag([0.02, 0.05, 0.01]) ** 2
    mean = np.zeros((n, 3))
    x = rng.multivariate_normal(np.zeros(3), cov, size=n)
    c = M.coverage(mean, np.broadcast_to(cov, (n, 3, 3)), x, floor_std=0.0)
    # binomial standard error at n = 20000 is < 0.004; allow 4 sigma
    assert c[0.5] == pytest.approx(0.5, abs=0.015)
    assert c[0.9] == pytest.approx(0.9, abs=0.01)
    # an overconfident estimate (covariance 100 times too small) covers much less
    tight = M.coverage(mean, np.broadcast_to(cov / 100, (n, 3, 3)), x, floor_std=0.0)
    assert tight[0.9] < 0.1


def test_student_t_nll_and_coverage_take_the_degrees_of_freedom():
    mean = np.array([0.1, 0.2, 0.7])
    cov = np.array([[4e-4, 1e-4, 0], [1e-4, 9e-4, 0], [0, 0, 1e-4]])
    xs = np.array([[0.12, 0.17, 0.71], [0.1, 0.2, 0.7], [0.3, 0.0, 0.6]])
    nu = 3.0
    floored = cov + M.COV_FLOOR_STD ** 2 * np.eye(3)
    # the t of that covariance has the scale matrix cov (nu - 2) / nu
    expected = -multivariate_t(mean, floored * (nu - 2) / nu, df=nu).logpdf(xs)
    got = M.gaussian_nll(np.broadcast_to(mean, xs.shape), np.broadcast_to(cov, (3, 3, 3)), xs, dof=nu)
    assert got == pytest.approx(expected, rel=1e-10)
    # inf entries are Gaussian, per sample
    mixed = M.gaussian_nll(np.broadcast_to(mean, xs.shape), np.broadcast_to(cov, (3, 3, 3)), xs,
                           dof=np.array([nu, math.inf, nu]))
    assert mixed[1] == pytest.approx(-multivariate_normal(mean, floored).logpdf(xs[1]), rel=1e-10)
    assert mixed[0] == pytest.approx(expected[0], rel=1e-10)
    # coverage of t samples under their own t regions is the level (binomial 4 sigma at n = 20000)
    rng = np.random.default_rng(8)
    n = 20000
    c = np.diag([0.02, 0.05, 0.01]) ** 2
    x = multivariate_t(np.zeros(3), c * (nu - 2) / nu, df=nu).rvs(n, random_state=rng)
    cov_t = M.coverage(np.zeros((n, 3)), np.broadcast_to(c, (n, 3, 3)), x, floor_std=0.0, dof=nu)
    cov_g = M.coverage(np.zeros((n, 3)), np.broadcast_to(c, (n, 3, 3)), x, floor_std=0.0)
    for level in (0.5, 0.9):
        assert cov_t[level] == pytest.approx(level, abs=4 * math.sqrt(level * (1 - level) / n))
    # read as a Gaussian of the same covariance, the same samples over-fill its 50 % region
    assert cov_g[0.5] > 0.5 + 4 * math.sqrt(0.25 / n)


def test_brier_and_ece_known_values():
    y = np.array([1, 0, 1, 1, 0], float)
    assert M.brier_score(y, y) == 0.0
    assert M.expected_calibration_error(y, y) == 0.0
    assert M.brier_score(np.full(5, 0.5), y) == pytest.approx(0.25)
    # constant 0.8 with 80 % positives: calibrated (ECE 0), Brier 0.8 * 0.04 + 0.2 * 0.64 = 0.16
    p = np.full(10, 0.8)
    y10 = np.array([1] * 8 + [0] * 2, float)
    assert M.expected_calibration_error(p, y10) == pytest.approx(0.0, abs=1e-12)
    assert M.brier_score(p, y10) == pytest.approx(0.16)
    # two bins: 0.9 with 50 % positives (gap 0.4, 4 items) and 0.1 with 0 % (gap 0.1, 6 items)
    p2 = np.array([0.9] * 4 + [0.1] * 6)
    y2 = np.array([1, 1, 0, 0] + [0] * 6, float)
    assert M.expected_calibration_error(p2, y2) == pytest.approx((4 * 0.4 + 6 * 0.1) / 10)
    assert math.isnan(M.brier_score([], []))


def test_reliability_bins_add_up_and_merge():
    p = np.array([0.0, 0.05, 0.55, 1.0, 1.0])
    y = np.array([0, 0, 1, 1, 0], float)
    b = M.reliability_bins(p, y)
    assert sum(b["n"]) == 5 and b["n"][0] == 2 and b["n"][5] == 1 and b["n"][9] == 2
    assert b["p_sum"][9] == pytest.approx(2.0) and b["y_sum"][9] == pytest.approx(1.0)
    merged = M.merge_bins([b, b])
    assert merged["n"][9] == 4 and M.ece_from_bins(merged) == pytest.approx(M.ece_from_bins(b))
