"""The predictability report (``predictability.md``, ``predictability.csv``): per scenario, the
twins' agreement with the truth (:mod:`experiments.evaluation.predictability`) and whether the
scenario is predictable to 5 cm; with an evaluation's ``trials.jsonl`` rows, each method's success
and hidden 50 % / 90 % coverage beside it, and success pooled over the predictable scenarios only.
Agreement and success are fractions in [0, 1] (per cent in the tables); intervals are 95 % bootstrap
intervals over seeds, from a fixed resampling seed (the same rows give the same report).
"""
from __future__ import annotations

import math
import os

import numpy as np

from experiments.evaluation.methods import method_label
from experiments.evaluation.predictability import TwinConfig
from experiments.evaluation.stats import bootstrap_ci

REPORT_FILE = "predictability.md"
CSV_FILE = "predictability.csv"


def _ci(values, rng) -> str:
    iv = bootstrap_ci(values, rng)
    if not math.isfinite(iv.estimate):
        return "–"
    if not math.isfinite(iv.low):
        return f"{100 * iv.estimate:.0f}"
    return f"{100 * iv.estimate:.0f} [{100 * iv.low:.0f}, {100 * iv.high:.0f}]"


def summarise(twins: list[dict], trials: list[dict], threshold: float) -> dict:
    """Per scenario: ``agreement`` (per seed), ``objects`` (per dynamic object, its agreement per
    seed), ``least`` (the object with the lowest mean agreement and that mean; None without dynamic
    objects), whether it is ``predictable`` (every object's mean agreement at least ``threshold``;
    without objects, the scenario's), per seed the largest of its objects' median twin distances (m); per method of
    ``trials`` (the evaluation's rows), its success per seed and its hidden 50 % / 90 % coverage per
    seed. Pooled, per method: success over
    the trials of predictable scenarios only (``pooled``) and the lowest predictable scenario's mean.
    Plain data (see :func:`report`)."""
    scen: dict[str, dict] = {}
    pairs = set()
    for r in twins:
        s = scen.setdefault(r["scenario"], {"agreement": [], "distance": [], "objects": {}, "methods": {}})
        s["agreement"].append(r["agreement"])
        s["distance"].append(max(r["distance_median"], default=math.nan))
        for o, a in zip(r["objects"], r["agree"]):
            s["objects"].setdefault(o, []).append(a)
        pairs.add((r["scenario"], r["seed"], r.get("engine", "bullet")))
    for s in scen.values():
        means = [(o, float(np.mean(v))) for o, v in s["objects"].items()]
        s["least"] = min(means, key=lambda m: m[1]) if means else None
        s["predictable"] = bool((s["least"][1] if means else np.mean(s["agreement"])) >= threshold)
    methods: list[str] = []
    for r in trials:
        # only the (scenario, seed) pairs twinned, under the same truth engine, parameters unscaled
        if (r.get("scenario"), r.get("seed"), r.get("engine") or "bullet") not in pairs \
                or float(r.get("param_scale") or 1.0) != 1.0:
            continue
        s = scen[r["scenario"]]
        label = method_label(r["method"], r["particles"])
        if label not in methods:
            methods.append(label)
        m = s["methods"].setdefault(label, {"success": [], "cover50": [], "cover90": []})
        m["success"].append(r.get("success_end"))
        m["cover50"].append(r.get("cover50_hidden"))
        m["cover90"].append(r.get("cover90_hidden"))
    methods.sort()  # the same report whatever order the trials ended in
    pooled = {}
    for label in methods:
        vals, means = [], {}
        for name, s in scen.items():
            m = s["methods"].get(label)
            if m is None or not s["predictable"]:
                continue
            v = [x for x in m["success"] if x is not None and math.isfinite(x)]
            vals += v
            if v:
                means[name] = float(np.mean(v))
        lowest = min(means, key=means.get) if means else None
        pooled[label] = {"success": vals, "lowest": lowest, "lowest_success": means.get(lowest, math.nan)}
    return {"threshold": threshold, "scenarios": scen, "methods": methods, "pooled": pooled}


def report(twins: list[dict], trials: list[dict], config: TwinConfig) -> tuple[str, list[dict]]:
    """The markdown report and the CSV rows (one per scenario) of :func:`summarise`. Intervals: 95 %
    bootstrap over seeds (fixed resampling seed: the same input gives the same report)."""
    s = summarise(twins, trials, config.threshold)
    rng = np.random.default_rng(0)
    n_tw = sorted({r["twins"] for r in twins})
    if config.position_std is not None:
        size = f"{1000 * config.position_std:g} mm (std per axis)"
    elif config.at == "last_seen":
        size = "the scenario's tracker noise (its position_std; hand_std for an object in the hand)"
    else:
        size = "the scenario's tracker noise (its position_std)"
    where = ("the run is the truth's until each dynamic object's last sighting, where the object (or, in "
             f"the hand, the hand) is moved by {size}" if config.at == "last_seen" else
             f"each dynamic object starts moved horizontally by {size}")
    params = (f"{'from there on' if config.at == 'last_seen' else 'from the start'}, the physical parameters the "
              "scenario randomises drawn again from its ranges (the estimator is told the nominal ones; every "
              f"parameter changed by up to {100 * config.param_scale:g} % from the start)"
              if config.params == "scenario" else
              f"its physical parameters the truth's, changed by up to {100 * config.param_scale:g} %")
    lines = [
        "# Predictability to 5 cm",
        "",
        f"{len(twins)} (scenario, seed) pairs, {', '.join(map(str, n_tw))} twins each: the same scene and hand "
        f"script; {where}; {params}. "
        "Agreement: twins whose "
        "object ends within 5 cm of the truth, on one of its supports (mean over objects, then seeds "
        "[95 % bootstrap interval]: comparable with success); least predictable object: the dynamic "
        "object the twins agree on least often (mean over seeds [interval]); distance: median over "
        "seeds of the median twin distance of the scene's most spread object. A scenario with an "
        f"object whose twins agree under {100 * config.threshold:.0f} % of the time is unpredictable "
        "to 5 cm (that object cannot be located to 5 cm, whatever the others do): success there is "
        "luck, and its regions' coverage is what to read.",
        "",
    ]
    head = ["scenario", "n", "twin agreement (%)", "least predictable object: agreement (%)",
            "twin distance, most spread object (cm)", "predictable"]
    for label in s["methods"]:
        head.append(f"{label} success (%)")
    head += [f"{label} 50% / 90% coverage, hidden" for label in s["methods"] if "K=" in label]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    csv_rows = []
    for name in sorted(s["scenarios"]):
        sc = s["scenarios"][name]
        least = sc["least"]
        row = [name, str(len(sc["agreement"])), _ci(sc["agreement"], rng),
               f"{least[0]}: {_ci(sc['objects'][least[0]], rng)}" if least else "–",
               f"{100 * float(np.median(sc['distance'])):.1f}" if sc["distance"] else "–",
               "yes" if sc["predictable"] else "**no**"]
        csv = {"scenario": name, "n": len(sc["agreement"]), "agreement": float(np.mean(sc["agreement"])),
               "least_object": least[0] if least else "", "least_agreement": least[1] if least else math.nan,
               "distance_most_spread_m": float(np.median(sc["distance"])) if sc["distance"] else math.nan,
               "predictable": sc["predictable"]}
        for label in s["methods"]:
            m = sc["methods"].get(label)
            row.append(_ci([x for x in m["success"] if x is not None], rng) if m else "–")
            if m:
                csv[f"{label} success"] = float(np.nanmean([x for x in m["success"] if x is not None]))
        for label in s["methods"]:
            if "K=" not in label:
                continue
            m = sc["methods"].get(label)
            cov = "–"
            if m:
                c50 = [x for x in m["cover50"] if x is not None and math.isfinite(x)]
                c90 = [x for x in m["cover90"] if x is not None and math.isfinite(x)]
                if c50 and c90:
                    cov = f"{np.mean(c50):.2f} / {np.mean(c90):.2f}"
                    csv[f"{label} cover50"], csv[f"{label} cover90"] = float(np.mean(c50)), float(np.mean(c90))
            row.append(cov)
        lines.append("| " + " | ".join(row) + " |")
        csv_rows.append(csv)
    if s["methods"]:
        unpredictable = sorted(n for n, sc in s["scenarios"].items() if not sc["predictable"])
        lines += ["", "## Success over the predictable scenarios", "",
                  "Pooled over their trials [95 % bootstrap interval]; left out: "
                  + (", ".join(f"`{n}`" for n in unpredictable) if unpredictable else "none") + ".", "",
                  "| method | trials | success (%) | lowest scenario | its success (%) |", "|---|---|---|---|---|"]
        for label in s["methods"]:
            p = s["pooled"][label]
            low = p["lowest"] or "–"
            low_s = f"{100 * p['lowest_success']:.0f}" if math.isfinite(p["lowest_success"]) else "–"
            lines.append(f"| {label} | {len(p['success'])} | {_ci(p['success'], rng)} | {low} | {low_s} |")
    return "\n".join(lines) + "\n", csv_rows


def write_report(out_dir: str, twins: list[dict], trials: list[dict], config: TwinConfig) -> str:
    """Write ``predictability.md`` and ``predictability.csv`` in ``out_dir``; returns the markdown."""
    import csv

    text, rows = report(twins, trials, config)
    with open(os.path.join(out_dir, REPORT_FILE), "w") as fh:
        fh.write(text)
    if rows:
        fields = list(dict.fromkeys(k for r in rows for k in r))
        with open(os.path.join(out_dir, CSV_FILE), "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            w.writeheader()
            w.writerows(rows)
    return text
