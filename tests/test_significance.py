"""The paired tests of experiments.evaluation.significance: the adaptive particle count against each
fixed K of the same method, on the rows of a small sweep (test_evaluate's reference sweep)."""
from __future__ import annotations

import pytest
import test_evaluate
from test_evaluate import K

reference = test_evaluate.reference
"""The small sweep of test_evaluate, its rows and its folder (a module fixture: run again here)."""


def test_the_adaptive_count_is_tested_against_each_fixed_k_of_the_same_method(reference):
    from experiments.evaluation.methods import AUTO
    from experiments.evaluation.significance import adaptive_tests, markdown_adaptive_section

    rows, _ = reference
    fixed = [r for r in rows if r["method"] == "particles"]
    # the same trials relabelled as an adaptive run whose hidden error is 1 cm larger in every pair
    auto = [dict(r, particles=AUTO, mean_particles=20.0,
                 err_hidden_median=(r["err_hidden_median"] + 0.01) if r.get("err_hidden_median") is not None
                 else None) for r in fixed]
    tests = adaptive_tests(rows + auto)
    assert len(tests) == 1 and tests[0]["baseline"] == f"particles K={K}" and tests[0]["mean_particles"] == 20.0
    t = tests[0]
    assert t["err_end_mean.median_diff"] == 0.0
    assert t["err_hidden_median.n"] > 0 and t["err_hidden_median.median_diff"] == pytest.approx(0.01)
    assert "particles (K=auto)" in markdown_adaptive_section(rows + auto)
    assert adaptive_tests(rows) == [] and markdown_adaptive_section(rows) == ""
