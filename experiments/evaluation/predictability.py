"""Which scenarios let anyone say where their objects end, to 5 cm (``scene-estimator predictability``).

The evaluation counts a final estimate a success when it is within 5 cm of the truth, on the right
support. Where an object falls off a table and rolls across the floor, no estimator can do that: the
outcome hangs on details no camera measures. This module measures it rather than asserting it.

For every (scenario, seed) of the evaluation, the scenario's variant (:func:`sample_variant`) is run
again as ``twins`` *twins*, each differing from the truth by what the robot could not have known:

* ``at="last_seen"`` (default): the run is the truth's until each dynamic object's last sighting (the
  last frame the camera saw it; the start if never), where the object is moved by Gaussian noise of
  the scenario's own tracker (``perception.position_std`` per horizontal axis; an object in the
  hand then moves with the hand, whose path is shifted by ``perception.hand_std`` per axis: the hand
  tracker's noise). What the camera saw last is known to that noise; what happened after, unseen, is
  physics.
* ``at="start"``: each dynamic object starts moved horizontally (:func:`~experiments.simulation.variants.twin_variant`):
  a test of chaos (with ``position_std`` 1 mm: does a millimetre change the outcome?).

``position_std`` (m), when given, replaces both noises. ``param_scale`` multiplies each physical
parameter the variant sets by a uniform factor in ``[1 - param_scale, 1 + param_scale]`` from the
start. With ``params="scenario"`` (default) those the scenario randomises (masses, frictions,
restitutions) are then drawn again from its ranges
(:func:`~experiments.simulation.variants.draw_parameters`), and an object takes them at its last
sighting (with ``at="start"``, at the start): the estimator is told the scenario's nominal values,
not the seed's, and what it saw of an object's motion before is the truth's (it may have learnt
something of them from it, which this ignores: agreement is then a lower bound). With
``params="scale"`` they stay the truth's (``at="start"`` then tests chaos: nothing unknown but a
millimetre and a percent). A twin
*agrees* on an object when its final position is within
:data:`~experiments.evaluation.metrics.SUCCESS_DISTANCE` of the truth's and its final support is one of
the truth's (:func:`~experiments.evaluation.metrics.truth_supports`). The *agreement* of a trial is the
fraction of (twin, dynamic object) pairs that agree, averaged as the evaluation averages success: over
the scene's dynamic objects, then over trials. It is the success of an estimator that knew everything
up to what the twins change and simulated it exactly (one twin drawn at random). An object whose
twins agree less often than ``threshold`` (its mean over seeds) cannot be located to 5 cm; a scenario
with such an object is *unpredictable to 5 cm*: its success measures luck, and its regions' coverage
is what to read. The test is per object, not on the scenario's mean agreement: a ball whose twins
agree in half the runs is not made predictable by a screen and a bin beside it that never move.

With an evaluation's ``trials.jsonl``, :func:`report` puts each method's success beside the
agreement, and pools success over the predictable scenarios only.

Rows are written to ``twins.jsonl`` as each (scenario, seed) ends; a run that is interrupted keeps
them and a rerun with the same settings starts from there. Each row depends only on its key: the
twins' generator is seeded from (scenario, seed), whatever the number of workers.
"""
from __future__ import annotations

import json
import math
import os
import zlib
from dataclasses import dataclass

import numpy as np

from experiments.evaluation import metrics as M
from experiments.evaluation.methods import method_label
from experiments.evaluation.stats import bootstrap_ci
from experiments.evaluation.sweep import read_rows

TWINS_FILE = "twins.jsonl"
REPORT_FILE = "predictability.md"
CSV_FILE = "predictability.csv"


AT = ("last_seen", "start")
"""Where twins are perturbed (see the module's docstring)."""

PARAMS = ("scenario", "scale")
"""How twins' physical parameters differ from the truth's (see the module's docstring)."""


@dataclass(frozen=True)
class TwinConfig:
    """How twins differ from the truth, and how many.

    * ``twins``: twins per (scenario, seed) (default 10).
    * ``at``: ``"last_seen"`` (each object at its last sighting, default) or ``"start"``.
    * ``position_std`` (m): the noise of the perturbation, per axis; ``None`` (default): the
      scenario's tracker noise (``perception.position_std`` for a free object, ``perception.hand_std``
      for one in the hand).
    * ``params``: ``"scenario"`` (default): the parameters the scenario randomises are drawn again
      from its ranges, taken at each object's last sighting; ``"scale"``: they stay the truth's.
    * ``param_scale``: each physical parameter the variant sets is multiplied by a uniform factor in
      ``[1 - param_scale, 1 + param_scale]`` from the start (default 0.01).
    * ``threshold``: a scenario with a dynamic object whose twins agree less often than this (mean
      over seeds) is unpredictable to 5 cm (default 0.85, the issue's floor on any one scenario's
      success).
    """

    twins: int = 10
    at: str = "last_seen"
    position_std: float | None = None
    params: str = "scenario"
    param_scale: float = 0.01
    threshold: float = 0.85
    engine: str = "bullet"

    def __post_init__(self):
        if not (isinstance(self.twins, int) and self.twins >= 1):
            raise ValueError(f"twins must be an integer >= 1, got {self.twins!r}")
        if self.at not in AT:
            raise ValueError(f"at must be one of {AT}, got {self.at!r}")
        if self.params not in PARAMS:
            raise ValueError(f"params must be one of {PARAMS}, got {self.params!r}")
        if self.position_std is not None and not (self.position_std >= 0 and math.isfinite(self.position_std)):
            raise ValueError(f"position_std must be finite and >= 0, got {self.position_std}")
        if not (0 <= self.param_scale < 1):
            raise ValueError(f"param_scale must be in [0, 1), got {self.param_scale}")
        if not (0 < self.threshold <= 1):
            raise ValueError(f"threshold must be in (0, 1], got {self.threshold}")
        from experiments.simulation.simulator import ENGINES
        if self.engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {self.engine!r}")

    def key(self, scenario: str, seed: int) -> str:
        """Identity of a (scenario, seed) row under these settings (``threshold`` is not part of it)."""
        p = "scene" if self.position_std is None else f"{self.position_std:g}"
        redrawn = "__rscenario" if self.params == "scenario" else ""  # rows of the older runs: "scale"
        engine = "" if self.engine == "bullet" else f"__{self.engine}"
        return f"{scenario}__s{seed}__n{self.twins}__{self.at}__p{p}__q{self.param_scale:g}{redrawn}{engine}"


def twin_rng(scenario: str, seed: int) -> np.random.Generator:
    """The twins' only generator for (scenario, seed): the same in every process."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(f"twins:{scenario}".encode())]))


def _run(variant, duration: float, seed: int, perturbations=None, engine: str = "bullet") -> tuple[list[dict], float]:
    """The truth rows of a run of ``variant`` under ``engine`` (as the simulator records them, with
    ``perturbations``, see :meth:`GroundTruth.run`) and its time step (s)."""
    from experiments.simulation.simulator import truth_class

    with truth_class(engine)(variant) as gt:
        result = gt.run(duration, np.random.default_rng([int(seed), 1]), perturbations)
        return result.truth, gt.dt


def last_sightings(truth: list[dict], object_ids: list[str], dt: float) -> dict[str, tuple[int, bool] | None]:
    """Per object: the simulation step (1-based) of the last frame in which it was visible, and whether
    it was in the hand then; the first step if it never was; ``None`` if it is visible in the last
    frame (nothing unseen to perturb)."""
    out: dict[str, tuple[int, bool] | None] = {}
    for o in object_ids:
        seen = [r for r in truth if r["objects"][o]["visible"]]
        if seen and seen[-1] is truth[-1]:
            out[o] = None
        elif seen:
            out[o] = (max(1, int(round(seen[-1]["t"] / dt))), bool(seen[-1]["objects"][o]["held"]))
        else:
            out[o] = (1, bool(truth[0]["objects"][o]["held"]) if truth else False)
    return out


def _perturbations(sightings: dict, index: dict[str, int], object_std: float, hand_std: float,
                   rng: np.random.Generator, params: dict[str, dict[str, float]] | None = None
                   ) -> dict[int, list[tuple]]:
    """One twin's moves at the last sightings: per object (in ``sightings`` order) three normal draws;
    a free object moves horizontally by ``object_std`` times the first two, one in the hand moves
    the hand by ``hand_std`` times all three. ``params``: physical parameters per object id that it
    takes at its last sighting (:func:`~experiments.simulation.variants.draw_parameters`; an object
    seen at the end keeps the truth's)."""
    out: dict[int, list[tuple]] = {}
    for o, when in sightings.items():
        z = rng.normal(0.0, 1.0, 3)
        if when is None:
            continue
        step, held = when
        offset = z * hand_std if held else np.array([z[0], z[1], 0.0]) * object_std
        out.setdefault(step, []).append((index[o], offset, (params or {}).get(o)))
    return out


def agreement(base: dict, twin: dict, object_ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Per object of ``object_ids``: whether ``twin``'s final truth row agrees with ``base``'s (within
    :data:`~experiments.evaluation.metrics.SUCCESS_DISTANCE`, a support in common) ``(D,)`` bool, and
    the distance between their final positions ``(D,)`` m."""
    ok, dist = [], []
    for o in object_ids:
        a, b = base["objects"][o], twin["objects"][o]
        d = float(np.linalg.norm(np.asarray(a["position"], float) - np.asarray(b["position"], float)))
        sa = M.truth_supports(base["relations"], o, bool(a["held"]))
        sb = M.truth_supports(twin["relations"], o, bool(b["held"]))
        ok.append(d < M.SUCCESS_DISTANCE and bool(sa & sb))
        dist.append(d)
    return np.array(ok, bool), np.array(dist)


def twin_row(job: tuple[str, int, TwinConfig]) -> dict:
    """Run one (scenario, seed): its truth and ``config.twins`` twins. Returns the row: ``key``,
    ``scenario``, ``seed``, ``objects`` (dynamic ids), per object ``agree`` (fraction of twins that
    agree) and ``distance_median`` (m), ``agreement`` (mean over objects) and the settings."""
    from experiments.scenarios import load_scenario
    from experiments.simulation.variants import draw_parameters, sample_variant, twin_variant

    name, seed, cfg = job
    scenario = load_scenario(name)
    variant = sample_variant(scenario, seed)
    ids = [o.id for o in variant.scene.objects if not o.static]
    index = {o: variant.scene.index(o) for o in ids}
    truth, dt = _run(variant, scenario.duration, seed, engine=cfg.engine)
    base = truth[-1]
    noise = scenario.perception
    object_std = noise.position_std if cfg.position_std is None else cfg.position_std
    hand_std = noise.hand_std if cfg.position_std is None else cfg.position_std
    sightings = last_sightings(truth, ids, dt)
    rng = twin_rng(name, seed)
    ok = np.zeros((cfg.twins, len(ids)), bool)
    dist = np.zeros((cfg.twins, len(ids)))
    for k in range(cfg.twins):
        if cfg.at == "start":
            twin, moves = twin_variant(variant, rng, object_std, cfg.param_scale), None
            if cfg.params == "scenario":  # every object takes them from the first step
                moves = {1: [(index[o], np.zeros(3), p) for o, p in draw_parameters(variant, rng).items()]}
        else:
            twin = twin_variant(variant, rng, 0.0, cfg.param_scale)
            params = draw_parameters(variant, rng) if cfg.params == "scenario" else None
            moves = _perturbations(sightings, index, object_std, hand_std, rng, params)
        ok[k], dist[k] = agreement(base, _run(twin, scenario.duration, seed, moves, cfg.engine)[0][-1], ids)
    agree = ok.mean(axis=0)
    return {"key": cfg.key(name, seed), "scenario": name, "seed": int(seed), "objects": ids,
            "agree": [float(a) for a in agree], "distance_median": [float(d) for d in np.median(dist, axis=0)],
            "agreement": float(agree.mean()) if ids else math.nan, "twins": cfg.twins, "at": cfg.at,
            "position_std": cfg.position_std, "params": cfg.params, "param_scale": cfg.param_scale,
            "engine": cfg.engine,
            "last_seen_s": {o: (None if w is None else round(w[0] * dt, 4)) for o, w in sightings.items()}}


def run_twins(names: list[str], seeds, config: TwinConfig, out_dir: str, workers: int = 1,
              progress=None) -> list[dict]:
    """Twin rows for ``names`` x ``seeds``, appended to ``out_dir/twins.jsonl`` as each ends; rows
    already there (same key) are not run again. Returns the rows of these jobs, in job order.
    ``progress``: called with each finished row."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, TWINS_FILE)
    done = {r["key"]: r for r in read_rows(path, repair=True)}  # a cut last line dropped
    jobs = [(n, int(s), config) for n in names for s in seeds]
    todo = [j for j in jobs if config.key(j[0], j[1]) not in done]
    if todo:
        with open(path, "a") as fh:
            def keep(row):
                fh.write(json.dumps(row) + "\n")
                fh.flush()
                done[row["key"]] = row
                if progress is not None:
                    progress(row)
            if workers > 1:
                import multiprocessing as mp
                with mp.get_context("spawn").Pool(workers) as pool:
                    for row in pool.imap_unordered(twin_row, todo, chunksize=1):
                        keep(row)
            else:
                for job in todo:
                    keep(twin_row(job))
    return [done[config.key(n, s)] for n, s, _ in jobs]


# --------------------------------------------------------------------------------------------------
# the report


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
