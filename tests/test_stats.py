"""Bootstrap intervals and the paired Wilcoxon test of experiments.evaluation.stats."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import wilcoxon

from experiments.evaluation.stats import bootstrap_ci, group_rng, paired_wilcoxon


def test_bootstrap_of_a_constant_is_the_constant():
    ci = bootstrap_ci([0.3] * 8, np.random.default_rng(0))
    assert (ci.estimate, ci.low, ci.high, ci.n) == (pytest.approx(0.3), pytest.approx(0.3), pytest.approx(0.3), 8)


def test_bootstrap_is_reproducible_with_the_same_generator_and_drops_nan():
    v = [1.0, 2.0, np.nan, 4.0, 8.0]
    a = bootstrap_ci(v, np.random.default_rng(5))
    b = bootstrap_ci(v, np.random.default_rng(5))
    assert a == b and a.n == 4 and a.estimate == pytest.approx(3.75)
    assert a.low <= a.estimate <= a.high


def test_bootstrap_interval_has_the_normal_width_for_a_large_sample():
    rng = np.random.default_rng(1)
    x = rng.normal(10.0, 2.0, size=400)
    ci = bootstrap_ci(x, np.random.default_rng(2), n_resamples=4000)
    half = 1.96 * x.std(ddof=1) / math.sqrt(len(x))  # 0.196
    assert ci.high - ci.low == pytest.approx(2 * half, rel=0.15)
    assert ci.low < 10.0 < ci.high


def test_bootstrap_degenerate_samples():
    one = bootstrap_ci([2.0], np.random.default_rng(0))
    assert one.estimate == 2.0 and math.isnan(one.low) and math.isnan(one.high)
    none = bootstrap_ci([np.nan], np.random.default_rng(0))
    assert none.n == 0 and math.isnan(none.estimate)
    med = bootstrap_ci([1, 2, 3, 100], np.random.default_rng(0), statistic=np.median)
    assert med.estimate == 2.5


def test_paired_wilcoxon_identical_samples_give_p_one():
    a = [0.1, 0.2, 0.3]
    t = paired_wilcoxon(a, a)
    assert t.p_value == 1.0 and t.n == 3 and t.n_nonzero == 0 and t.median_diff == 0.0


def test_paired_wilcoxon_detects_a_consistent_improvement_and_matches_scipy():
    rng = np.random.default_rng(3)
    paper = rng.uniform(0.05, 0.3, size=10)
    particles = paper - rng.uniform(0.01, 0.05, size=10)  # always better
    t = paired_wilcoxon(particles, paper)
    assert t.n == 10 and t.median_diff < 0
    assert t.p_value == pytest.approx(2 / 2 ** 10)  # exact two-sided p of all-negative signs
    ref = wilcoxon(np.round(particles - paper, 12))
    assert t.p_value == pytest.approx(ref.pvalue) and t.statistic == pytest.approx(ref.statistic)


def test_paired_wilcoxon_drops_pairs_with_nan():
    t = paired_wilcoxon([1.0, np.nan, 3.0, 4.0], [0.0, 1.0, np.nan, 3.5])
    assert t.n == 2
    assert math.isnan(paired_wilcoxon([np.nan], [1.0]).p_value)
    with pytest.raises(ValueError):
        paired_wilcoxon([1.0], [1.0, 2.0])


def test_group_rng_is_stable_and_distinct():
    a = group_rng("cup", "paper", 1).integers(0, 2**31, 3)
    b = group_rng("cup", "paper", 1).integers(0, 2**31, 3)
    c = group_rng("cup", "particles", 64).integers(0, 2**31, 3)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
