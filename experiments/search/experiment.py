"""The search experiment: trials over scenarios and seeds, resumable, and its report.

``run_search_sweep`` runs every :class:`~experiments.search.trial.SearchTrialSpec` of a
:class:`SearchSweepConfig` missing from ``OUT/search_trials.jsonl`` (on a pool of spawned
processes; each trial runs its worlds in its own process, so the rows do not depend on the number
of workers), appends one line per finished trial as it ends (an interrupted run keeps them; the next
run skips them), and writes ``search_summary.md``, ``search_summary.csv`` and ``search.png``.

Statistics, per method, pooled over the trials that had a hidden object and per scenario: mean
looks to find (a target not found within :data:`~experiments.search.trial.MAX_LOOKS` counts
``MAX_LOOKS + 1``) and mean cost to find (the cost of every look made, found or not) with 95 %
bootstrap intervals over trials; success within 1, 2 and 3 looks with exact (Clopper-Pearson)
intervals; and Wilcoxon signed-rank tests of the closed-loop planner against each other method on
looks and on cost, paired by trial (scenario and seed).
"""
from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.evaluation.stats import bootstrap_ci, group_rng, paired_wilcoxon
from experiments.evaluation.sweep import append_results, local_results, read_rows
from experiments.evaluation.tracker_report import clopper_pearson
from experiments.search.trial import MAX_LOOKS, SEARCH_METHODS, SearchTrialSpec, run_search_trial

TRIALS_FILE = "search_trials.jsonl"
SEARCH_SCENARIOS = ("cup_falls_behind_box", "ball_dropped_into_box", "box_emptied_into_box", "ball_in_moving_box",
                    "cluttered_table", "cup_stashed_behind_screen", "ball_bounces_behind_screen")
"""The built-in scenarios that end with an object the camera cannot see (``all``)."""
REFERENCE = "closed-loop"
ALL = "all scenarios"


@dataclass(frozen=True)
class SearchSweepConfig:
    """Scenarios x seeds, ``particles`` of the particle estimator, ``duration`` (s) overriding the
    scenarios'."""

    scenarios: tuple[str, ...] = SEARCH_SCENARIOS
    seeds: tuple[int, ...] = tuple(range(20))
    particles: int = 64
    duration: float | None = None

    def __post_init__(self):
        if not self.scenarios or not self.seeds:
            raise ValueError("SearchSweepConfig needs at least one scenario and one seed")
        if self.particles < 1:
            raise ValueError(f"SearchSweepConfig.particles must be >= 1, got {self.particles}")

    def trials(self) -> list[SearchTrialSpec]:
        return [SearchTrialSpec(s, seed, self.particles, self.duration) for s in self.scenarios for seed in self.seeds]


def _safe_trial(spec: SearchTrialSpec) -> dict:
    import traceback
    try:
        return run_search_trial(spec)
    except Exception:  # reported with the trial's key; the sweep goes on
        return {"row": None, "key": spec.key, "error": traceback.format_exc()}


def run_search_sweep(config: SearchSweepConfig, out_dir: str | os.PathLike, workers: int = 1,
                     progress: bool = True, report: bool = True) -> list[dict]:
    """Run the trials of ``config`` not yet in ``out_dir/search_trials.jsonl``; returns the rows of
    the sweep's trials in order. A trial that raises is reported on stderr (with its traceback) and
    left out of the file, so that the next run retries it."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / TRIALS_FILE
    specs = config.trials()
    done = {r["key"]: r for r in read_rows(path, repair=True)}
    todo = [s for s in specs if s.key not in done]
    failed = []
    if todo:
        def keep(res: dict) -> None:
            if res["row"] is not None:
                done[res["row"]["key"]] = res["row"]

        failed = append_results(local_results(todo, workers, _safe_trial), path, len(specs), len(specs) - len(todo),
                                progress, keep, allow_nan=True)
    rows = [done[s.key] for s in specs if s.key in done]
    if report and rows:
        write_search_report(rows, out)
    if failed:
        raise RuntimeError(f"{len(failed)} of {len(specs)} search trial(s) failed; run again to retry them")
    return rows


# --------------------------------------------------------------------------------------------------
# the report


def method_results(rows: list[dict], method: str) -> list[dict]:
    """``method``'s part of every row that had a target, with the row's scenario and seed."""
    return [{**r["methods"][method], "scenario": r["scenario"], "seed": r["seed"]}
            for r in rows if r.get("target") and method in r["methods"]]


def summarize_search(rows: list[dict]) -> list[dict]:
    """One record per (scenario or :data:`ALL`, method): ``n``, ``looks`` / ``cost`` (mean with
    ``_lo`` / ``_hi`` bootstrap bounds), ``within1..3`` (rates with Clopper-Pearson bounds),
    ``found`` (rate within :data:`MAX_LOOKS`), ``first_p`` (mean of the method's own probability
    that its first look finds the object) and ``planning_ms`` (mean)."""
    scenarios = sorted({r["scenario"] for r in rows if r.get("target")})
    out = []
    for sc in scenarios + [ALL]:
        sel = [r for r in rows if sc == ALL or r["scenario"] == sc]
        for m in SEARCH_METHODS:
            res = method_results(sel, m)
            if not res:
                continue
            rec = {"scenario": sc, "method": m, "n": len(res)}
            for field in ("looks", "cost"):
                ci = bootstrap_ci([x[field] for x in res], group_rng("search", sc, m, field))
                rec[field], rec[field + "_lo"], rec[field + "_hi"] = ci.estimate, ci.low, ci.high
            for k in (1, 2, 3):
                hits = sum(x["looks"] <= k for x in res)
                lo, hi = clopper_pearson(hits, len(res))
                rec[f"within{k}"], rec[f"within{k}_lo"], rec[f"within{k}_hi"] = hits / len(res), lo, hi
            rec["found"] = float(np.mean([x["found"] for x in res]))
            rec["first_p"] = float(np.nanmean([x["first_p"] for x in res])) if any(
                np.isfinite(x["first_p"]) for x in res) else math.nan
            rec["planning_ms"] = float(np.nanmean([x["planning_ms"] for x in res]))
            out.append(rec)
    return out


def search_tests(rows: list[dict], reference: str = REFERENCE) -> list[dict]:
    """Wilcoxon signed-rank tests of ``reference`` against every other method, on looks and on cost,
    paired by trial, pooled over scenarios. ``median_diff`` < 0: the reference needs fewer."""
    ref = {(x["scenario"], x["seed"]): x for x in method_results(rows, reference)}
    out = []
    for m in SEARCH_METHODS:
        if m == reference:
            continue
        other = {(x["scenario"], x["seed"]): x for x in method_results(rows, m)}
        keys = sorted(set(ref) & set(other))
        if not keys:
            continue
        for field in ("looks", "cost"):
            t = paired_wilcoxon([ref[k][field] for k in keys], [other[k][field] for k in keys])
            a = np.mean([ref[k][field] for k in keys])
            b = np.mean([other[k][field] for k in keys])
            out.append({"method": m, "metric": field, "n": t.n, "mean_reference": float(a), "mean_other": float(b),
                        "median_diff": t.median_diff, "p_value": t.p_value})
    return out


def _ci(rec: dict, field: str, fmt: str = "{:.2f}", scale: float = 1.0) -> str:
    v, lo, hi = rec[field], rec[field + "_lo"], rec[field + "_hi"]
    if not math.isfinite(v):
        return "-"
    body = fmt.format(scale * v)
    if math.isfinite(lo) and math.isfinite(hi):
        body += f" [{fmt.format(scale * lo)}, {fmt.format(scale * hi)}]"
    return body


def markdown_search(summary: list[dict], tests: list[dict]) -> str:
    """``search_summary.md``: the pooled table, the per-scenario table and the paired tests."""
    lines = ["# Hidden-object search", "",
             f"Looks to find (not found within {MAX_LOOKS} looks: {MAX_LOOKS + 1}), cost to find (1 per look + 1 "
             "per metre of camera travel), success within 1, 2 and 3 looks; mean [95 % interval] over trials "
             "(bootstrap; Clopper-Pearson for rates).", ""]
    head = ("| scenario | method | n | looks | cost | within 1 look (%) | within 2 (%) | within 3 (%) | "
            "own P(first look finds) | planning (ms/look) |")
    for title, pick in (("All scenarios", lambda r: r["scenario"] == ALL),
                        ("Per scenario", lambda r: r["scenario"] != ALL)):
        lines += [f"## {title}", "", head, "|" + "---|" * 10]
        for r in summary:
            if pick(r):
                lines.append(f"| {r['scenario']} | {r['method']} | {r['n']} | {_ci(r, 'looks')} | {_ci(r, 'cost')} | "
                             f"{_ci(r, 'within1', '{:.0f}', 100)} | {_ci(r, 'within2', '{:.0f}', 100)} | "
                             f"{_ci(r, 'within3', '{:.0f}', 100)} | {r['first_p']:.2f} | {r['planning_ms']:.0f} |")
        lines.append("")
    if tests:
        lines += [f"## {REFERENCE} against the others (Wilcoxon signed-rank, paired by trial)", "",
                  f"| method | metric | n | {REFERENCE} mean | method mean | median difference | p |",
                  "|---|---|---|---|---|---|---|"]
        for t in tests:
            lines.append(f"| {t['method']} | {t['metric']} | {t['n']} | {t['mean_reference']:.2f} | "
                         f"{t['mean_other']:.2f} | {t['median_diff']:+.2f} | {t['p_value']:.2g} |")
        lines.append("")
    return "\n".join(lines)


def plot_search(summary: list[dict], path: str | os.PathLike) -> Path:
    """Success within k looks (k = 1, 2, 3) per method, pooled, with the exact 95 % intervals."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pooled = [r for r in summary if r["scenario"] == ALL]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.8 / max(len(pooled), 1)
    for i, r in enumerate(pooled):
        x = np.arange(3) + (i - (len(pooled) - 1) / 2) * width
        v = np.array([r[f"within{k}"] for k in (1, 2, 3)])
        err = np.array([[v[k - 1] - r[f"within{k}_lo"], r[f"within{k}_hi"] - v[k - 1]] for k in (1, 2, 3)]).T
        ax.bar(x, 100 * v, width, yerr=100 * err, capsize=2, label=r["method"])
    ax.set_xticks(np.arange(3), ["1 look", "2 looks", "3 looks"])
    ax.set_ylabel("found within (%)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=8, ncol=3, loc="lower right")
    ax.set_title(f"Hidden-object search, {pooled[0]['n'] if pooled else 0} trials")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_search_report(rows: list[dict], out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write ``search_summary.md``, ``search_summary.csv``, ``search_tests.csv`` and ``search.png``."""
    out = Path(out_dir)
    summary = summarize_search(rows)
    tests = search_tests(rows)
    paths = {"md": out / "search_summary.md", "csv": out / "search_summary.csv", "tests": out / "search_tests.csv"}
    paths["md"].write_text(markdown_search(summary, tests), encoding="utf-8")
    for key, recs in (("csv", summary), ("tests", tests)):
        with open(paths[key], "w", newline="", encoding="utf-8") as fh:
            if recs:
                w = csv.DictWriter(fh, fieldnames=list(recs[0]), lineterminator="\n")
                w.writeheader()
                w.writerows(recs)
    if summary:
        paths["png"] = plot_search(summary, out / "search.png")
    return paths
