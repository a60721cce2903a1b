"""The evaluation's summary of trial rows: per (scenario, method, K), and per (method, K) over all
scenarios (:data:`ALL`), the number of trials and each metric's mean and 95 % percentile-bootstrap
interval over seeds, in the rows' raw units (m, s, probabilities); :class:`Column` names a metric,
its header, scale and format, and :data:`SUMMARY_COLUMNS` / :data:`EXTRA_COLUMNS` are those
summarised. Rendered and written by :mod:`experiments.evaluation.report`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

from experiments.evaluation.methods import METHODS
from experiments.evaluation.metrics import ACTIONS
from experiments.evaluation.stats import bootstrap_ci, group_rng


@dataclass(frozen=True)
class Column:
    """A summarised metric: row field (``timing.x`` for timing), header, scale factor and format."""

    field: str
    header: str
    scale: float = 1.0
    fmt: str = "{:.2f}"


SUMMARY_COLUMNS: tuple[Column, ...] = (
    Column("err_hidden_median", "hidden err. median (cm)", 100.0, "{:.1f}"),
    Column("err_hidden_p90", "hidden err. p90 (cm)", 100.0, "{:.1f}"),
    Column("err_end_mean", "final err. (cm)", 100.0, "{:.1f}"),
    Column("success_end", "success (%)", 100.0, "{:.0f}"),
    Column("success_end_hidden", "success, hidden objects (%)", 100.0, "{:.0f}"),
    Column("ontop_f1", "isOnTop F1", 1.0, "{:.2f}"),
    Column("isin_f1", "isIn F1", 1.0, "{:.2f}"),
    Column("event_f1", "event F1", 1.0, "{:.2f}"),
    Column("event_latency", "event latency (s)", 1.0, "{:.2f}"),
    Column("nll_hidden_median", "NLL hidden (median)", 1.0, "{:.1f}"),
    Column("cover90_hidden", "90% coverage hidden", 1.0, "{:.2f}"),
    Column("timing.update_ms_median", "update (ms)", 1.0, "{:.1f}"),
)
"""Columns of the main table of ``summary.md`` (mean and 95 % bootstrap interval over seeds)."""

EXTRA_COLUMNS: tuple[Column, ...] = (
    Column("err_median", "err. median (cm)", 100.0), Column("err_p90", "err. p90 (cm)", 100.0),
    Column("err_end_max", "final err. max (cm)", 100.0),
    Column("ontop_acc", "isOnTop acc."), Column("isin_acc", "isIn acc."),
    Column("event_precision", "event precision"), Column("event_recall", "event recall"),
    Column("event_f1_loose", "event F1 (1.5 s window)"),
    Column("event_latency_loose", "event latency (1.5 s window, s)"),
    *(Column(f"{a.lower()}_{m}", f"{a} {h}") for a in ACTIONS
      for m, h in (("f1", "F1"), ("precision", "precision"), ("recall", "recall"), ("latency", "latency (s)"))),
    Column("nll", "NLL"), Column("nll_median", "NLL median"), Column("nll_hidden", "NLL hidden"),
    Column("cover50", "50% coverage"), Column("cover90", "90% coverage"),
    Column("cover50_hidden", "50% coverage hidden"),
    Column("brier_plausible", "Brier P(plausible)"), Column("ece_plausible", "ECE P(plausible)"),
    Column("brier_isin", "Brier P(isIn)"), Column("ece_isin", "ECE P(isIn)"),
    Column("brier_isontop", "Brier P(isOnTop)"), Column("ece_isontop", "ECE P(isOnTop)"),
    Column("err_reappear_median", "err. at re-appearance (cm)", 100.0),
    Column("gate_rate_reappear", "re-appearance in 99% gate"),
    Column("nees_seen_median", "NEES seen (median; 2.37)"), Column("nees_hidden_median", "NEES hidden (median; 2.37)"),
    Column("nees_hidden_mean", "NEES hidden (mean; 3)"),
    Column("invariant_violations", "particles inside static geometry (count)", 1.0, "{:.1f}"),
    Column("invariant_depth_max", "deepest inside static geometry (mm)", 1000.0, "{:.1f}"),
    Column("timing.update_ms_p95", "update p95 (ms)"), Column("timing.peak_rss_mb", "peak memory (MB)"),
    Column("timing.trial_s", "trial (s)"), Column("mean_particles", "mean K", 1.0, "{:.0f}"),
)

ALL = "all scenarios"


def _value(row: dict, name: str) -> float:
    src = row
    if name.startswith("timing."):
        src, name = row.get("timing") or {}, name[len("timing."):]
    v = src.get(name)
    return math.nan if v is None else float(v)


def _method_order(rows) -> list[tuple[str, int]]:
    order = {m: i for i, m in enumerate(METHODS)}
    pairs = sorted({(r["method"], r["particles"]) for r in rows}, key=lambda p: (order.get(p[0], 99), p[1]))
    return pairs


def summarize(rows: list[dict], columns: Iterable[Column] = SUMMARY_COLUMNS + EXTRA_COLUMNS) -> list[dict]:
    """One summary record per (scenario, method, K), plus per (method, K) over all scenarios: the
    number of trials ``n`` and, per column, ``<field>`` (mean), ``<field>.lo`` and ``<field>.hi``
    (95 % percentile-bootstrap interval over the trials; seeds within a scenario), in raw units.

    Deterministic: values are ordered by (scenario, seed) and every group has its own generator."""
    columns = tuple(columns)
    scenarios = sorted({r["scenario"] for r in rows})
    out = []
    groups = [(sc, m, k) for sc in scenarios for (m, k) in _method_order(rows)]
    if len(scenarios) > 1:
        groups += [(ALL, m, k) for (m, k) in _method_order(rows)]
    for sc, m, k in groups:
        sel = sorted((r for r in rows if r["method"] == m and r["particles"] == k
                      and (sc == ALL or r["scenario"] == sc)), key=lambda r: (r["scenario"], r["seed"]))
        if not sel:
            continue
        rec = {"scenario": sc, "method": m, "particles": k, "n": len(sel)}
        if sel[0].get("config"):
            rec["config"] = sel[0]["config"]
        for c in columns:
            ci = bootstrap_ci([_value(r, c.field) for r in sel], group_rng(sc, m, k, c.field))
            rec[c.field], rec[c.field + ".lo"], rec[c.field + ".hi"] = ci.estimate, ci.low, ci.high
        out.append(rec)
    return out
