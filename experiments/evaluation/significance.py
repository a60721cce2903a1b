"""The evaluation's paired tests: Wilcoxon signed-rank tests, paired by (scenario, seed), of every
particle method against the paper's reasoner (:func:`paired_tests`, on :data:`TEST_METRICS`) and of
the adaptive particle count against each fixed K of the same method (:func:`adaptive_tests`, on
:data:`AUTO_TEST_METRICS`, with its Markdown section). A test record holds, per metric field,
``<field>.n`` (pairs), ``<field>.median_diff`` (method - baseline, raw units) and ``<field>.p``
(two-sided p-value).
"""
from __future__ import annotations

import io
import math

import numpy as np

from experiments.evaluation.methods import AUTO, get_method, method_label
from experiments.evaluation.stats import paired_wilcoxon
from experiments.evaluation.summary import ALL, _method_order, _value

TEST_METRICS: tuple[tuple[str, str, float], ...] = (
    ("err_hidden_median", "hidden err. median (cm)", 100.0),
    ("err_end_mean", "final err. (cm)", 100.0),
    ("success_end", "success (%)", 100.0),
    ("event_f1", "event F1", 1.0),
)
"""Metrics of the paired tests (particle methods against the paper's reasoner, paired by seed)."""


def _paired(rec: dict, mine: dict, base: dict, keys: list, metrics) -> dict:
    """``rec`` with, for each ``(field, heading, scale)`` of ``metrics``, the Wilcoxon signed-rank
    test of the rows ``mine`` against ``base`` (both by (scenario, seed)) over ``keys``:
    ``<field>.n``, ``<field>.median_diff`` (mine - base) and ``<field>.p``."""
    for fieldname, _h, _s in metrics:
        t = paired_wilcoxon([_value(mine[x], fieldname) for x in keys], [_value(base[x], fieldname) for x in keys])
        rec[fieldname + ".n"], rec[fieldname + ".median_diff"], rec[fieldname + ".p"] = t.n, t.median_diff, t.p_value
    return rec


def _test_cells(t: dict, metrics) -> list[str]:
    """The cells of one test record (:func:`_paired`): median difference, p-value and pairs."""
    cells = []
    for f, _h, s in metrics:
        d, p, n = t[f + ".median_diff"], t[f + ".p"], t[f + ".n"]
        cells.append("–" if not (n and math.isfinite(d)) else
                     f"{d * s:+.2f} (p={p:.3g}, n={n})" if math.isfinite(p) else f"{d * s:+.2f} (n={n})")
    return cells


def paired_tests(rows: list[dict], baseline: str = "paper") -> list[dict]:
    """Wilcoxon signed-rank tests of every particle method against ``baseline``, per scenario and
    over all scenarios, paired by (scenario, seed), for each of :data:`TEST_METRICS`."""
    base = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == baseline}
    if not base:
        return []
    out = []
    scenarios = sorted({r["scenario"] for r in rows})
    for m, k in _method_order(rows):
        if not get_method(m).uses_particles:
            continue
        mine = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == m and r["particles"] == k}
        for sc in scenarios + ([ALL] if len(scenarios) > 1 else []):
            keys = sorted(x for x in mine if x in base and (sc == ALL or x[0] == sc))
            if not keys:
                continue
            out.append(_paired({"scenario": sc, "method": m, "particles": k, "baseline": baseline},
                               mine, base, keys, TEST_METRICS))
    return out


AUTO_TEST_METRICS = TEST_METRICS + (("cover90_hidden", "90% coverage hidden", 1.0),
                                     ("err_hidden_early_median", "hidden err. median, first s (cm)", 100.0),
                                     ("cover90_hidden_early", "90% coverage hidden, first s", 1.0),
                                     ("cover90_hidden_late", "90% coverage hidden, later", 1.0))
"""Metrics of the paired tests of the adaptive particle count against each fixed K (*first s*: the
hidden samples of the first second of each occlusion, :data:`~experiments.evaluation.metrics.EARLY_HIDDEN`;
*later*: the others)."""


def adaptive_tests(rows: list[dict]) -> list[dict]:
    """Wilcoxon signed-rank tests of each particle method run with the adaptive count (``particles``
    :data:`~experiments.evaluation.methods.AUTO`) against the same method at each fixed K of the
    rows, over all scenarios, paired by (scenario, seed), for each of :data:`AUTO_TEST_METRICS`
    (the difference is auto - fixed)."""
    out = []
    for m, k in _method_order(rows):
        if k != AUTO or not get_method(m).uses_particles:
            continue
        mine = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == m and r["particles"] == AUTO}
        for m2, k2 in _method_order(rows):
            if m2 != m or k2 == AUTO:
                continue
            base = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == m and r["particles"] == k2}
            keys = sorted(x for x in mine if x in base)
            if not keys:
                continue
            rec = {"scenario": ALL, "method": m, "particles": AUTO, "baseline": f"{m} K={k2}",
                   "mean_particles": float(np.mean([mine[x].get("mean_particles", np.nan) for x in keys]))}
            out.append(_paired(rec, mine, base, keys, AUTO_TEST_METRICS))
    return out


def markdown_adaptive_section(rows: list[dict]) -> str:
    """The adaptive count against each fixed K (:func:`adaptive_tests`), or nothing."""
    tests = adaptive_tests(rows)
    if not tests:
        return ""
    buf = io.StringIO()
    buf.write("\n## The adaptive particle count against fixed K (Wilcoxon signed-rank, by seed)\n\n"
              "Cells: median difference (auto - fixed K) and two-sided p-value; n = pairs.\n\n")
    head = ["method", "against", "mean K (auto)"] + [h for _f, h, _s in AUTO_TEST_METRICS]
    buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
    for t in tests:
        cells = [method_label(t["method"], t["particles"]), t["baseline"], f"{t['mean_particles']:.0f}"]
        cells += _test_cells(t, AUTO_TEST_METRICS)
        buf.write("| " + " | ".join(cells) + " |\n")
    return buf.getvalue()
