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

With an evaluation's ``trials.jsonl``, :func:`~experiments.evaluation.predictability_report.report`
puts each method's success beside the agreement, and pools success over the predictable scenarios
only.

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
from experiments.evaluation.sweep import read_rows

TWINS_FILE = "twins.jsonl"


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
                from experiments.evaluation.sweep import spawn_pool
                with spawn_pool(workers) as pool:
                    for row in pool.imap_unordered(twin_row, todo, chunksize=1):
                        keep(row)
            else:
                for job in todo:
                    keep(twin_row(job))
    return [done[config.key(n, s)] for n, s, _ in jobs]
