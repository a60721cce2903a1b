"""The Kalman-tracker experiment's section of the evaluation report (issue: tracker feedback).

Four methods of :mod:`experiments.evaluation.methods` compared on the scenarios with hidden objects: the
tracker alone, the tracker kept alive by the estimator (``tracker-feedback``), the estimator alone
(``particles``) and the estimator fed by the tracker (``particles-on-tracker``). Per method, pooled
over those scenarios and seeds:

* hidden-object error (mean over trials of the per-trial median, cm) and error at re-appearance;
* the gate rate: re-appearances inside the 99 % gate over all re-appearances (each trial's rate times
  its count), with a Clopper-Pearson 95 % interval;
* NEES seen / hidden: the mean over trials of the per-trial median (chi-square(3) median 2.37), and
  the mean over trials of the per-trial mean NEES while hidden against its 95 % band
  (:func:`~experiments.evaluation.tracking_metrics.nees_band`);
* the paired Wilcoxon test of ``particles-on-tracker`` against ``particles`` (hidden-object error,
  by scenario and seed).
"""
from __future__ import annotations

import io
import math

import numpy as np

from experiments.evaluation.stats import paired_wilcoxon
from experiments.evaluation.tracking_metrics import nees_band

TRACKER_METHODS = ("tracker", "tracker-feedback", "particles", "particles-on-tracker")


def clopper_pearson(hits: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of ``hits / n`` (NaNs when ``n`` is 0)."""
    if n == 0:
        return math.nan, math.nan
    from scipy.stats import beta  # scipy.stats costs a second to import: only where it is used

    a = (1.0 - confidence) / 2.0
    lo = 0.0 if hits == 0 else float(beta.ppf(a, hits, n - hits + 1))
    hi = 1.0 if hits == n else float(beta.ppf(1.0 - a, hits + 1, n - hits))
    return lo, hi


def _finite(values) -> np.ndarray:
    v = np.array([math.nan if x is None else float(x) for x in values])
    return v[np.isfinite(v)]


def tracker_rows(rows: list[dict]) -> dict[str, list[dict]]:
    """The trial rows of the four methods on the scenarios where some object is hidden, by method."""
    hidden = {r["scenario"] for r in rows if (r.get("n_hidden") or 0) > 0}
    return {m: sorted((r for r in rows if r["method"] == m and r["scenario"] in hidden),
                      key=lambda r: (r["scenario"], r["seed"])) for m in TRACKER_METHODS}


def method_stats(sel: list[dict]) -> dict:
    """Pooled figures of one method's trials (see the module docstring)."""
    n_re = [int(r.get("n_reappear") or 0) for r in sel]
    hits = int(round(sum(n * (r.get("gate_rate_reappear") or 0.0) for n, r in zip(n_re, sel))))
    total = int(sum(n_re))
    means = _finite(r.get("nees_hidden_mean") for r in sel)
    out = {"trials": len(sel), "reappear": total, "gate_hits": hits,
           "gate_rate": hits / total if total else math.nan, "gate_ci": clopper_pearson(hits, total),
           "err_hidden": float(np.mean(_finite(r.get("err_hidden_median") for r in sel))) if sel else math.nan,
           "err_reappear": float(np.mean(_finite(r.get("err_reappear_median") for r in sel)))
           if len(_finite(r.get("err_reappear_median") for r in sel)) else math.nan,
           "nees_seen": float(np.mean(_finite(r.get("nees_seen_median") for r in sel)))
           if len(_finite(r.get("nees_seen_median") for r in sel)) else math.nan,
           "nees_hidden": float(np.mean(_finite(r.get("nees_hidden_median") for r in sel)))
           if len(_finite(r.get("nees_hidden_median") for r in sel)) else math.nan,
           "nees_hidden_mean": float(np.mean(means)) if len(means) else math.nan,
           "nees_band": nees_band(len(means)) if len(means) else (math.nan, math.nan)}
    return out


def markdown_tracker_section(rows: list[dict]) -> str:
    """The report's section, or '' when the four methods did not all run."""
    by = tracker_rows(rows)
    if not all(by[m] for m in TRACKER_METHODS):
        return ""
    buf = io.StringIO()
    scenarios = sorted({r["scenario"] for m in TRACKER_METHODS for r in by[m]})
    buf.write("\n## Kalman tracker and physics feedback (scenarios with hidden objects)\n\n"
              f"Scenarios: {', '.join(scenarios)}. Errors in cm (mean over trials of the per-trial median); "
              "gate: re-appearing detections inside the 99 % gate / all re-appearances [Clopper-Pearson 95 %]; "
              "NEES: mean over trials of the per-trial median (consistent: 2.37) and of the per-trial mean "
              "while hidden against its 95 % band (consistent: 3).\n\n")
    head = ["method", "trials", "hidden err.", "err. at re-appearance", "in gate", "NEES seen (median)",
            "NEES hidden (median)", "NEES hidden (mean) [95 % band]"]
    buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
    for m in TRACKER_METHODS:
        s = method_stats(by[m])
        lo, hi = s["gate_ci"]
        gate = "–" if not s["reappear"] else f"{s['gate_hits']}/{s['reappear']} = {s['gate_rate']:.2f} [{lo:.2f}, {hi:.2f}]"
        b0, b1 = s["nees_band"]
        inside = "inside" if b0 <= s["nees_hidden_mean"] <= b1 else "outside"
        nees_mean = "–" if not math.isfinite(s["nees_hidden_mean"]) else \
            f"{s['nees_hidden_mean']:.2f} [{b0:.2f}, {b1:.2f}] {inside}"
        cells = [m, str(s["trials"]), _f(s["err_hidden"], 100), _f(s["err_reappear"], 100), gate,
                 _f(s["nees_seen"]), _f(s["nees_hidden"]), nees_mean]
        buf.write("| " + " | ".join(cells) + " |\n")
    mine = {(r["scenario"], r["seed"]): r for r in by["particles-on-tracker"]}
    base = {(r["scenario"], r["seed"]): r for r in by["particles"]}
    keys = sorted(set(mine) & set(base))
    t = paired_wilcoxon([mine[k].get("err_hidden_median") if mine[k].get("err_hidden_median") is not None
                         else math.nan for k in keys],
                        [base[k].get("err_hidden_median") if base[k].get("err_hidden_median") is not None
                         else math.nan for k in keys])
    if t.n:
        buf.write(f"\nEstimator fed by the tracker against the estimator on raw detections, hidden-object error "
                  f"(Wilcoxon signed-rank, paired by scenario and seed): median difference "
                  f"{t.median_diff * 100:+.2f} cm, p = {t.p_value:.3g}, n = {t.n}.\n")
    return buf.getvalue()


def _f(v: float, scale: float = 1.0) -> str:
    return "–" if not math.isfinite(v) else f"{v * scale:.2f}"
