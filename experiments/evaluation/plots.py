"""Figures of an evaluation (matplotlib, Agg backend; PNG files).

* ``views_<scenario>.png``: top (x-y) and side (x-z) views in the style of the paper's figures:
  perceived trajectory in pink, the particle estimator's estimate in green (other methods in thinner
  lines), its final particle cloud shaded by weight, the truth dashed;
* ``error_<scenario>.png``: position error over time per method, with the particle estimator's
  uncertainty band (2 x the RMS radius of its covariance, sqrt(trace)) and hidden intervals shaded;
* ``tracker_<scenario>.png``: the same for the Kalman tracker's experiment (tracker alone, with
  feedback, estimator alone, estimator fed by the tracker), when the four methods ran;
* ``reliability.png``: reliability diagrams of P(plausible), P(isIn), P(isOnTop) per method;
* ``update_time.png``: time per reasoning step against the number of particles;
* ``metrics.png``: hidden-object error and success per scenario and method, with 95 % intervals.

The per-scenario figures read the traces written by the sweep (``traces/<key>.json``); the others
only need the trial rows and the summary.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from experiments.evaluation.methods import METHODS, get_method, method_label  # noqa: E402
from experiments.evaluation.metrics import merge_bins  # noqa: E402

PINK = "#e75480"
GREEN = "#2e8b57"
OTHER = {"paper": "#1f77b4", "last-seen": "#7f7f7f", "tracker": "#ff7f0e", "tracker-feedback": "#d62728",
         "particles-on-tracker": "#e377c2"}
ABLATION = ["#9467bd", "#8c564b", "#bcbd22", "#17becf"]


def method_color(method: str) -> str:
    """Green for the particle estimator, fixed colours for the baselines and ablations."""
    if method == "particles":
        return GREEN
    if method in OTHER:
        return OTHER[method]
    names = [m for m in METHODS if m.startswith("particles-") and m not in OTHER]
    return ABLATION[names.index(method) % len(ABLATION)] if method in names else "#d62728"


def _interesting(trace: dict, limit: int = 3) -> list[int]:
    """Objects worth drawing: the ones hidden longest, then the ones that moved most."""
    truth = np.asarray(trace["truth"], float)
    vis = np.asarray(trace["visible"], bool)
    if truth.size == 0:
        return []
    hidden = (~vis).sum(axis=0)
    moved = np.linalg.norm(truth.max(axis=0) - truth.min(axis=0), axis=-1)
    score = hidden * 1.0 + moved * 1e-3 + (moved > 0.01) * 0.5
    order = [int(i) for i in np.argsort(-score, kind="stable") if score[i] > 0]
    return order[:limit] or [0]


def _primary(traces: dict[str, dict]) -> str | None:
    for m in ("particles", *[m for m in traces if get_method(m).uses_particles], "paper"):
        if m in traces:
            return m
    return next(iter(traces), None)


def plot_views(traces: dict[str, dict], path: str | Path, title: str = "") -> Path:
    """Top and side views of one scenario and seed. ``traces``: method name -> trace (as written by
    :func:`experiments.evaluation.trials.run_trial`)."""
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    main = _primary(traces)
    ref = traces[main]
    objs = _interesting(ref)
    for ax, (a, b), name in ((axes[0], (0, 1), "top view (x-y)"), (axes[1], (0, 2), "side view (x-z)")):
        for n, i in enumerate(objs):
            oid = ref["object_ids"][i]
            tr = np.asarray(ref["truth"], float)[:, i]
            ax.plot(tr[:, a], tr[:, b], "k--", lw=1.2, label="truth" if n == 0 else None)
            ax.annotate(oid, tr[-1, [a, b]], fontsize=8, xytext=(4, 4), textcoords="offset points")
            obs = np.asarray(ref["observed"].get(oid) or np.zeros((0, 4)), float)
            if len(obs):
                ax.plot(obs[:, 1 + a], obs[:, 1 + b], ".-", color=PINK, ms=3, lw=0.8,
                        label="perceived" if n == 0 else None)
            for m, trc in traces.items():
                est = np.asarray(trc["estimate"], float)
                if est.size == 0:
                    continue
                est = est[:, i]
                main_m = m == main
                ax.plot(est[:, a], est[:, b], "-", color=method_color(m), lw=2.0 if main_m else 1.0,
                        alpha=1.0 if main_m else 0.7,
                        label=(f"estimate: {method_label(m, trc['particles'])}" if n == 0 else None))
            if ref.get("cloud") is not None:
                cloud = np.asarray(ref["cloud"], float)[:, i]
                w = np.asarray(ref["cloud_weights"], float)
                w = w / w.max() if w.max() > 0 else w
                order = np.argsort(w)
                ax.scatter(cloud[order, a], cloud[order, b], c=w[order], cmap="Greens", vmin=-0.2, vmax=1.0,
                           s=14, edgecolors="none", alpha=0.8,
                           label="final particles (shade: weight)" if n == 0 else None)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if b == 1 else "z (m)")
        ax.set_title(name)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(title or f"{ref['scenario']} (seed {ref['seed']})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_error_over_time(traces: dict[str, dict], path: str | Path, title: str = "") -> Path:
    """Position error (cm) against time for the most hidden objects, one panel each: one line per
    method, the uncertainty band (0 to 2 sqrt(trace cov)) of the particle methods, hidden time
    shaded grey."""
    path = Path(path)
    main = _primary(traces)
    ref = traces[main]
    objs = _interesting(ref)
    fig, axes = plt.subplots(len(objs), 1, figsize=(9, 2.6 * len(objs)), squeeze=False, sharex=True)
    tt = np.asarray(ref["truth_t"], float)
    truth = np.asarray(ref["truth"], float)
    vis = np.asarray(ref["visible"], bool)
    for ax, i in zip(axes[:, 0], objs):
        hid = ~vis[:, i]
        if hid.any():
            ax.fill_between(tt, 0, 1, where=hid, transform=ax.get_xaxis_transform(), color="0.88",
                            label="hidden (truth)", step="mid")
        for m, trc in traces.items():
            t = np.asarray(trc["t"], float)
            if t.size == 0:
                continue
            j = np.clip(np.searchsorted(tt, t + 1e-6, side="right") - 1, 0, len(tt) - 1)
            err = 100 * np.linalg.norm(np.asarray(trc["estimate"], float)[:, i] - truth[j, i], axis=-1)
            ax.plot(t, err, color=method_color(m), lw=1.8 if m == main else 1.0,
                    label=method_label(m, trc["particles"]))
            if get_method(m).uses_particles:
                std = 100 * np.asarray(trc["std"], float)[:, i]
                ax.fill_between(t, 0, 2 * std, color=method_color(m), alpha=0.18,
                                label=f"2 sigma ({m})")
        ax.set_ylabel(f"{ref['object_ids'][i]}\nerror (cm)")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle(title or f"{ref['scenario']} (seed {ref['seed']}): error over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_reliability(rows: list[dict], path: str | Path) -> Path:
    """Reliability diagrams pooled over all trials of each method (bins stored in the rows)."""
    path = Path(path)
    kinds = ("plausible", "isIn", "isOnTop")
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
    pairs = sorted({(r["method"], r["particles"]) for r in rows},
                   key=lambda p: (list(METHODS).index(p[0]), p[1]))
    for ax, kind in zip(axes, kinds):
        ax.plot([0, 1], [0, 1], ":", color="0.5", lw=1)
        for m, k in pairs:
            bins = merge_bins([r["reliability"][kind] for r in rows
                               if r["method"] == m and r["particles"] == k and r.get("reliability")])
            n = np.asarray(bins["n"], float)
            ok = n > 0
            if not ok.any():
                continue
            mp = np.asarray(bins["p_sum"])[ok] / n[ok]
            fy = np.asarray(bins["y_sum"])[ok] / n[ok]
            size = 10 + 60 * np.sqrt(n[ok] / n.max())
            ax.plot(mp, fy, "-", color=method_color(m), lw=1)
            ax.scatter(mp, fy, s=size, color=method_color(m), label=method_label(m, k), zorder=3)
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel(f"predicted P({kind})")
        ax.set_ylabel("observed frequency")
        ax.set_title(f"P({kind})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Reliability (marker area ~ number of predictions)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_update_time(rows: list[dict], path: str | Path) -> Path:
    """Median time per reasoning step (ms) against the number of particle worlds, per method
    (quartiles over trials as error bars); the paper's reasoner is the K = 1 point."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(6, 4.2))
    by = {}
    for r in rows:
        v = (r.get("timing") or {}).get("update_ms_median")
        if v is None or r["particles"] < 1:
            continue
        by.setdefault(r["method"], {}).setdefault(r["particles"], []).append(v)
    for m, d in by.items():
        ks = sorted(d)
        med = np.array([np.median(d[k]) for k in ks])
        lo = np.array([np.percentile(d[k], 25) for k in ks])
        hi = np.array([np.percentile(d[k], 75) for k in ks])
        ax.errorbar(ks, med, yerr=[med - lo, hi - med], fmt="o-", color=method_color(m), capsize=3, label=m)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("particles K")
    ax.set_ylabel("update time per reasoning step (ms)")
    ax.axhline(80, color="0.5", ls=":", lw=1)
    ax.text(1, 80, " real time (0.08 s horizon)", fontsize=7, va="bottom", color="0.4")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_metrics(summary: list[dict], path: str | Path) -> Path:
    """Grouped bars per scenario: hidden-object error (cm) and final success (%), one bar per
    method with its 95 % bootstrap interval."""
    path = Path(path)
    scen = [s for s in dict.fromkeys(r["scenario"] for r in summary)]
    pairs = list(dict.fromkeys((r["method"], r["particles"]) for r in summary))
    fig, axes = plt.subplots(2, 1, figsize=(max(8, 1.3 * len(scen) + 2), 7), sharex=True)
    width = 0.8 / max(len(pairs), 1)
    x = np.arange(len(scen))
    for ax, (f, scale, ylabel) in zip(axes, (("err_hidden_median", 100, "hidden error median (cm)"),
                                              ("success_end", 100, "success at the end (%)"))):
        for j, (m, k) in enumerate(pairs):
            vals, lo, hi = [], [], []
            for sc in scen:
                rec = next((r for r in summary if r["scenario"] == sc and r["method"] == m and r["particles"] == k), None)
                v = rec.get(f) if rec else None
                v = math.nan if v is None else v
                a = rec.get(f + ".lo") if rec else None
                b = rec.get(f + ".hi") if rec else None
                vals.append(v * scale)
                lo.append(v * scale - (a * scale if a is not None and math.isfinite(a) else v * scale))
                hi.append((b * scale if b is not None and math.isfinite(b) else v * scale) - v * scale)
            ax.bar(x + (j - (len(pairs) - 1) / 2) * width, vals, width, yerr=[lo, hi], capsize=2,
                   color=method_color(m), label=method_label(m, k))
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=7)
    axes[1].set_xticks(x)
    axes[1].set_xticklabels(scen, rotation=30, ha="right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def load_traces(out_dir: str | Path, keys: set[str] | None = None) -> list[dict]:
    """Traces in ``out_dir/traces`` (only those of ``keys`` when given)."""
    folder = Path(out_dir) / "traces"
    out = []
    if not folder.is_dir():
        return out
    for p in sorted(folder.glob("*.json")):
        if keys is not None and p.stem not in keys:
            continue
        with open(p, encoding="utf-8") as fh:
            out.append(json.load(fh))
    return out


def make_figures(rows: list[dict], summary: list[dict], out_dir: str | Path) -> list[Path]:
    """All figures of a sweep into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    paths = []
    if not rows:
        return paths
    traces = load_traces(out, {r["key"] for r in rows})
    by_scenario: dict[str, dict[int, dict[str, dict]]] = {}
    for t in traces:  # one trace per method: the one with the most particles
        slot = by_scenario.setdefault(t["scenario"], {}).setdefault(t["seed"], {})
        if t["method"] not in slot or t["particles"] > slot[t["method"]]["particles"]:
            slot[t["method"]] = t
    for sc, seeds in sorted(by_scenario.items()):
        seed = min(seeds)
        tr = seeds[seed]
        paths.append(plot_views(tr, out / f"views_{sc}.png"))
        paths.append(plot_error_over_time(tr, out / f"error_{sc}.png"))
        four = ("tracker", "tracker-feedback", "particles", "particles-on-tracker")
        if all(m in tr for m in four):
            paths.append(plot_error_over_time({m: tr[m] for m in four}, out / f"tracker_{sc}.png",
                                              f"{sc} (seed {seed}): Kalman tracker with and without physics"))
    paths.append(plot_reliability(rows, out / "reliability.png"))
    paths.append(plot_update_time(rows, out / "update_time.png"))
    paths.append(plot_metrics([r for r in summary], out / "metrics.png"))
    return paths
