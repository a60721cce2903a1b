"""The evaluation's report: per scenario and method, the mean and 95 % bootstrap interval of each
metric over seeds (:mod:`experiments.evaluation.summary`); paired tests against the paper's reasoner
(:mod:`experiments.evaluation.significance`); the events by action pooled over trials; the truth
conditions (engine, parameter scale) side by side; ``summary.md``, ``summary.csv``, ``tests.csv`` and
the figures."""
from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path

from experiments.evaluation.methods import method_label
from experiments.evaluation.metrics import ACTIONS, precision_recall_f1
from experiments.evaluation.significance import TEST_METRICS, _test_cells, markdown_adaptive_section, paired_tests
from experiments.evaluation.summary import ALL, SUMMARY_COLUMNS, Column, _method_order, summarize

CONDITION_COLUMNS: tuple[Column, ...] = (
    Column("success_end", "success (%)", 100.0, "{:.0f}"),
    Column("success_end_hidden", "success, hidden (%)", 100.0, "{:.0f}"),
    Column("cover90_hidden", "90% coverage hidden", 1.0, "{:.2f}"),
    Column("err_hidden_median", "hidden err. median (cm)", 100.0, "{:.1f}"),
    Column("event_f1", "event F1", 1.0, "{:.2f}"),
    Column("invariant_violations", "inside static (count)", 1.0, "{:.1f}"),
)
"""Columns of the table that sets the truth conditions (engine, parameter scale) side by side."""


def condition(row: dict) -> tuple[str, float]:
    """The truth condition of a trial row: ``(engine, param_scale)`` (rows written before either
    existed are Bullet's at scale 1)."""
    return str(row.get("engine") or "bullet"), float(row.get("param_scale") or 1.0)


def condition_label(cond: tuple[str, float]) -> str:
    engine, scale = cond
    name = {"bullet": "Bullet", "mujoco": "MuJoCo"}.get(engine, engine)
    return f"{name} truth" + ("" if scale == 1.0 else f", parameters x{scale:g}")


def _conditions(rows) -> list[tuple[str, float]]:
    """The conditions of ``rows``: MuJoCo first (the headline truth), then Bullet; scales ascending."""
    rank = {"mujoco": 0, "bullet": 1}
    return sorted({condition(r) for r in rows}, key=lambda c: (rank.get(c[0], 2), c[0], c[1]))


def _cell(rec: dict, c: Column) -> str:
    v, lo, hi = rec.get(c.field), rec.get(c.field + ".lo"), rec.get(c.field + ".hi")
    if v is None or not math.isfinite(v):
        return "–"
    s = c.fmt.format(v * c.scale)
    if lo is not None and math.isfinite(lo):
        s += " [" + c.fmt.format(lo * c.scale) + ", " + c.fmt.format(hi * c.scale) + "]"
    return s


def markdown_summary(summary: list[dict], tests: list[dict], columns=SUMMARY_COLUMNS, title: bool = True) -> str:
    """The Markdown report: the main table (mean [95 % CI] over seeds), the paired tests and the
    calibration table."""
    buf = io.StringIO()
    if title:
        n = sum(rec["n"] for rec in summary if rec["scenario"] != ALL)
        buf.write(f"# Evaluation summary\n\n{n} trials. Cells: mean over seeds [95 % bootstrap interval].\n"
                  "Errors in cm; 'hidden' = samples where the true object is not visible to the camera; "
                  "success = final error < 5 cm and correct support/container.\n\n")
        configs = sorted({rec["config"] for rec in summary if rec.get("config")})
        for c in configs:
            buf.write(f"Particle methods with the estimator configuration `{c}`.\n\n")
    head = ["scenario", "method", "n"] + [c.header for c in columns]
    buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
    for rec in summary:
        cells = [rec["scenario"], method_label(rec["method"], rec["particles"]), str(rec["n"])]
        cells += [_cell(rec, c) for c in columns]
        buf.write("| " + " | ".join(cells) + " |\n")
    if tests:
        buf.write("\n## Paired tests against the paper's reasoner (Wilcoxon signed-rank, by seed)\n\n"
                  "Cells: median difference (method - paper) and two-sided p-value; n = pairs.\n\n")
        head = ["scenario", "method"] + [h for _f, h, _s in TEST_METRICS]
        buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
        for t in tests:
            cells = [t["scenario"], method_label(t["method"], t["particles"])] + _test_cells(t, TEST_METRICS)
            buf.write("| " + " | ".join(cells) + " |\n")
    calib = [Column("brier_plausible", "Brier P(plausible)"), Column("ece_plausible", "ECE P(plausible)"),
             Column("brier_isin", "Brier P(isIn)", 1.0, "{:.3f}"), Column("ece_isin", "ECE P(isIn)", 1.0, "{:.3f}"),
             Column("brier_isontop", "Brier P(isOnTop)", 1.0, "{:.3f}"),
             Column("ece_isontop", "ECE P(isOnTop)", 1.0, "{:.3f}"),
             Column("cover50_hidden", "50% cov. hidden"), Column("cover90_hidden", "90% cov. hidden"),
             Column("timing.peak_rss_mb", "peak memory (MB)", 1.0, "{:.0f}")]
    pooled = [r for r in summary if r["scenario"] == ALL] or summary
    buf.write("\n## Calibration (pooled over scenarios)\n\n")
    head = ["method"] + [c.header for c in calib]
    buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
    for rec in pooled:
        cells = [method_label(rec["method"], rec["particles"]) + ("" if rec["scenario"] == ALL else
                                                                   f" ({rec['scenario']})")]
        cells += [_cell(rec, c) if c.field in rec else "–" for c in calib]
        buf.write("| " + " | ".join(cells) + " |\n")
    return buf.getvalue()


def pooled_event_counts(rows: list[dict]) -> list[dict]:
    """Per (method, K) and action (:data:`~experiments.evaluation.metrics.ACTIONS`), the event counts
    summed over all trials (``n_true``, ``n_est``, ``n_matched``) and the pooled ``precision``,
    ``recall`` and ``f1`` they give (NaN where undefined). Rows without the counts are skipped."""
    out = []
    for m, k in _method_order(rows):
        sel = [r for r in rows if r["method"] == m and r["particles"] == k]
        for a in ACTIONS:
            a_ = a.lower()
            have = [r for r in sel if f"{a_}_true" in r]
            if not have:
                continue
            n_true, n_est, n_match = (sum(int(r[f"{a_}_{c}"]) for r in have) for c in ("true", "est", "matched"))
            out.append({"method": m, "particles": k, "action": a, "trials": len(have), "n_true": n_true,
                        "n_est": n_est, "n_matched": n_match, **precision_recall_f1(n_match, n_est, n_true)})
    return out


def markdown_event_section(rows: list[dict]) -> str:
    """The events by action, pooled over all trials (:func:`pooled_event_counts`), as Markdown."""
    counts = pooled_event_counts(rows)
    if not counts:
        return ""
    buf = io.StringIO()
    buf.write("\n## Events by action (pooled over all trials, 0.5 s window)\n\n"
              "| method | action | true | estimated | matched | precision | recall | F1 |\n"
              "|---|---|---|---|---|---|---|---|\n")
    for c in counts:
        def f(v):
            return "–" if not math.isfinite(v) else f"{v:.2f}"
        buf.write(f"| {method_label(c['method'], c['particles'])} | {c['action']} | {c['n_true']} | "
                  f"{c['n_est']} | {c['n_matched']} | {f(c['precision'])} | {f(c['recall'])} | {f(c['f1'])} |\n")
    return buf.getvalue()


def write_summary_csv(summary: list[dict], path: str | os.PathLike) -> None:
    """``summary.csv``: one line per (scenario, method, K), raw units, mean / lo / hi per metric."""
    if not summary:
        Path(path).write_text("")
        return
    fields = list(dict.fromkeys(k for rec in summary for k in rec))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, lineterminator="\n", restval="")
        w.writeheader()
        for rec in summary:
            w.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else
                            (repr(v) if isinstance(v, float) else v)) for k, v in rec.items()})


def markdown_conditions(summaries: dict[tuple[str, float], list[dict]]) -> str:
    """The truth conditions side by side: per condition and method, pooled over scenarios (or the one
    scenario), the :data:`CONDITION_COLUMNS`."""
    buf = io.StringIO()
    head = ["truth", "method", "n"] + [c.header for c in CONDITION_COLUMNS]
    buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
    for cond, summary in summaries.items():
        pooled = [r for r in summary if r["scenario"] == ALL] or summary
        for rec in pooled:
            cells = [condition_label(cond), method_label(rec["method"], rec["particles"]), str(rec["n"])]
            cells += [_cell(rec, c) if c.field in rec else "–" for c in CONDITION_COLUMNS]
            buf.write("| " + " | ".join(cells) + " |\n")
    return buf.getvalue()


def write_report(rows: list[dict], out_dir: str | os.PathLike, plots: bool = True) -> dict[str, Path]:
    """Write ``summary.md``, ``summary.csv``, ``tests.csv`` and the figures for ``rows``; returns the
    paths.

    Rows of several truth conditions (:func:`condition`: engine, parameter scale) are summarised and
    tested per condition: ``summary.md`` opens with the conditions side by side
    (:func:`markdown_conditions`), then has one section per condition (MuJoCo's first); the CSV
    records carry ``engine`` and ``param_scale``; the figures are drawn for the first condition."""
    out = Path(out_dir)
    conds = _conditions(rows)
    from experiments.evaluation.tracker_report import markdown_tracker_section
    paths = {"summary.md": out / "summary.md", "summary.csv": out / "summary.csv"}
    if len(conds) == 1:
        summary = summarize(rows)
        tests = paired_tests(rows)
        text = (markdown_summary(summary, tests) + markdown_adaptive_section(rows) + markdown_event_section(rows)
                + markdown_tracker_section(rows))
    else:
        summaries, summary, tests = {}, [], []
        parts = []
        for cond in conds:
            sel = [r for r in rows if condition(r) == cond]
            s_c, t_c = summarize(sel), paired_tests(sel)
            summaries[cond] = s_c
            tag = {"engine": cond[0], "param_scale": cond[1]}
            summary += [{**tag, **rec} for rec in s_c]
            tests += [{**tag, **rec} for rec in t_c]
            parts.append(f"\n# {condition_label(cond)}\n\n" + markdown_summary(s_c, t_c, title=False)
                         + markdown_adaptive_section(sel) + markdown_event_section(sel) + markdown_tracker_section(sel))
        n = len(rows)
        text = (f"# Evaluation summary\n\n{n} trials under {len(conds)} truth conditions (the engine that "
                "simulated the ground truth, and a factor on its frictions and restitution against the "
                "nominal values the estimator is given). Cells: mean over seeds [95 % bootstrap interval]. "
                "Errors in cm; 'hidden' = samples where the true object is not visible to the camera; "
                "success = final error < 5 cm and correct support/container; 'inside static' = particle "
                "entries more than 1 cm inside static geometry, per trial.\n\n## The truth conditions side "
                "by side (pooled over scenarios)\n\n" + markdown_conditions(summaries) + "".join(parts))
    paths["summary.md"].write_text(text, encoding="utf-8")
    write_summary_csv(summary, paths["summary.csv"])
    if tests:
        paths["tests.csv"] = out / "tests.csv"
        write_summary_csv(tests, paths["tests.csv"])
    if plots:
        from experiments.evaluation.plots import make_figures
        first = [r for r in rows if condition(r) == conds[0]]
        plot_summary = summary if len(conds) == 1 else summarize(first)
        for p in make_figures(first, plot_summary, out):
            paths[p.name] = p
    return paths
