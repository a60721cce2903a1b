"""The Kalman-tracker section of the evaluation report: exact binomial intervals, pooled figures of
hand-built trial rows, and the Markdown section."""
import math

import pytest
from scipy.stats import binomtest

from experiments.evaluation.tracker_report import (
    TRACKER_METHODS,
    clopper_pearson,
    markdown_tracker_section,
    method_stats,
)
from experiments.evaluation.tracking_metrics import nees_band


@pytest.mark.parametrize("hits, n", [(0, 40), (40, 40), (28, 40), (3, 7)])
def test_clopper_pearson_matches_scipys_exact_interval(hits, n):
    lo, hi = clopper_pearson(hits, n)
    ref = binomtest(hits, n).proportion_ci(0.95, method="exact")
    assert lo == pytest.approx(ref.low, abs=1e-12) and hi == pytest.approx(ref.high, abs=1e-12)
    assert all(math.isnan(v) for v in clopper_pearson(0, 0))


def _row(method, scenario, seed, n_re, gate, nees_mean, err=0.02):
    return {"method": method, "scenario": scenario, "seed": seed, "n_hidden": 5, "n_reappear": n_re,
            "gate_rate_reappear": gate, "err_hidden_median": err, "err_reappear_median": 0.05 if n_re else None,
            "nees_seen_median": 2.0, "nees_hidden_median": 2.5, "nees_hidden_mean": nees_mean}


def test_method_stats_pool_reappearances_and_average_the_nees_means():
    rows = [_row("tracker-feedback", "a", 0, 2, 0.5, 3.0), _row("tracker-feedback", "a", 1, 1, 1.0, 5.0),
            _row("tracker-feedback", "b", 0, 0, None, None)]
    s = method_stats(rows)
    assert (s["gate_hits"], s["reappear"]) == (2, 3) and s["gate_rate"] == pytest.approx(2 / 3)
    assert s["nees_hidden_mean"] == pytest.approx(4.0) and s["nees_band"] == nees_band(2)
    assert s["err_hidden"] == pytest.approx(0.02)


def test_section_needs_all_four_methods_and_reports_the_paired_test():
    rows = [_row(m, "a", seed, 1, 1.0, 3.0, err=0.02 + 0.001 * seed * (m == "particles-on-tracker"))
            for m in TRACKER_METHODS for seed in range(6)]
    text = markdown_tracker_section(rows)
    assert "| tracker-feedback | 6 |" in text and "6/6 = 1.00" in text and "Wilcoxon" in text
    assert markdown_tracker_section([r for r in rows if r["method"] != "tracker"]) == ""
