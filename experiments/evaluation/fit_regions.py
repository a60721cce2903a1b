"""Fit the distribution the particle estimator reports for a position, on seeds the evaluation does
not use (``scene-estimator fit-priors --regions``).

What is fitted (:class:`estimator.config.NoiseConfig`): ``covariance_floor_std`` (m),
``covariance_speed_time`` (s) and ``position_dof``. The estimator reports, for a dynamic object, a
multivariate Student-t with ``position_dof`` degrees of freedom and covariance

    particle covariance + floor_std^2 I + (speed_time * speed)^2 I,

the speed term only while the object is not detected (``speed``, m/s: how fast its headline position
moved over the update). The particles alone are both too wide and too narrow: a hidden object at rest
is within millimetres of where they put it, one that rolls or rides in a jerked box is centimetres off
while they agree with each other; the errors have heavier tails than a Gaussian's.

How: the particle estimator runs with the three switched off (floor 0, speed term 0, Gaussian) on
every built-in scenario x ``seeds``; every (reasoning step, dynamic object hidden in the truth) is a
sample of the residual (truth minus headline position, m), the particles' covariance and the speed
(from consecutive steps' headline positions, as the estimator measures it). Every combination of the
grids is scored on the estimator's own regions, what a user reads (not with the evaluation's
:data:`~experiments.evaluation.metrics.COV_FLOOR_STD`, which the evaluation adds to every method's
covariance for the point estimates' sake; the fit also reports the coverage with it, ``as_evaluated``):
the fraction of samples inside the 50 % and 90 % regions (:func:`estimator.belief.region_radius_sq`),
per trial, averaged over the trials of each scenario and over all trials, as the evaluation averages
its per-trial coverages (a trial in which an object is hidden for one update counts as much as one in
which it is hidden for twenty). The fit is the
combination whose pooled coverages are nearest to 0.5 and 0.9 (sum of squared differences) among
those where every scenario's 90 % coverage is at least ``min_scenario`` (all of them if none is).
A grid search, deterministic; the trials are seeded as the evaluation seeds them.
"""
from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass

import numpy as np

from experiments.evaluation import metrics as M
from experiments.evaluation.fit_priors import FIT_SEEDS

FLOORS = (0.001, 0.002, 0.003, 0.005, 0.007)
"""Grid of ``covariance_floor_std`` (m). No zero: particles that collapsed onto one value would
report a singular covariance, a region of no volume."""
RIDGE_STD = 1e-6
"""m: added (squared) to every scored covariance so that one without spread (the terms off, a
collapsed particle set) stays invertible: a micrometre, nothing a region notices."""
SPEED_TIMES = (0.0, 0.025, 0.05, 0.075, 0.1, 0.15)
"""Grid of ``covariance_speed_time`` (s)."""
DOFS = (2.5, 3.0, 4.0, 6.0, 10.0, math.inf)
"""Grid of ``position_dof`` (``inf``: Gaussian, ``None`` in the configuration)."""
LEVELS = (0.5, 0.9)
"""The regions whose coverage is fitted."""
OFF = {"noise": {"covariance_floor_std": 0.0, "covariance_speed_time": 0.0, "position_dof": None}}
"""The estimator configuration the samples are collected with (the fitted terms off)."""


@dataclass(frozen=True)
class RegionSamples:
    """``residual (N, 3)`` m (truth minus headline position), ``cov (N, 3, 3)`` m^2 (the particles'),
    ``speed (N,)`` m/s, ``scenario (N,)`` int index into ``scenarios``, ``trial (N,)`` int, the
    trial each sample comes from (``arange(N)``: every sample counts alike)."""

    residual: np.ndarray
    cov: np.ndarray
    speed: np.ndarray
    scenario: np.ndarray
    scenarios: tuple[str, ...]
    trial: np.ndarray

    def __post_init__(self):
        n = len(self.residual)
        shapes = (self.residual.shape == (n, 3), self.cov.shape == (n, 3, 3), self.speed.shape == (n,),
                  self.scenario.shape == (n,), np.shape(self.trial) == (n,))
        if not all(shapes):
            raise ValueError(f"RegionSamples: inconsistent shapes {self.residual.shape}, {self.cov.shape}, "
                             f"{self.speed.shape}, {self.scenario.shape}, {np.shape(self.trial)}")

    def save(self, path) -> None:
        """Write the samples to ``path`` (``.npz``), through a temporary file renamed into place (an
        interrupted write leaves no partial file)."""
        _save_npz(path, residual=self.residual, cov=self.cov, speed=self.speed, scenario=self.scenario,
                  scenarios=np.array(self.scenarios, dtype=str), trial=self.trial)

    @classmethod
    def load(cls, path) -> "RegionSamples":
        """Samples written by :meth:`save`; a missing or malformed file is an
        :class:`~physics.errors.InputError` naming it."""
        keys = ("residual", "cov", "speed", "scenario", "scenarios", "trial")
        z = _load_npz(path, keys, "not a file of region samples (from before 'trial' was kept: collect again)")
        return cls(z["residual"], z["cov"], z["speed"], z["scenario"].astype(int),
                   tuple(str(n) for n in z["scenarios"]), z["trial"].astype(int))


def _save_npz(path, **arrays) -> None:
    """``np.savez`` through a temporary file renamed into place."""
    import os

    path = os.fspath(path)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _load_npz(path, keys: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the ``.npz`` at ``path``; a missing or malformed file is an
    :class:`~physics.errors.InputError` naming it, ``what`` saying what it is not."""
    from physics.errors import InputError

    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in keys}
    except (OSError, KeyError, ValueError) as e:
        raise InputError(f"{path}: {what} ({e})") from None


def collect_region_samples(scenarios: list[str] | None = None, seeds=FIT_SEEDS, particles: int = 64,
                           workers: int = 1, parts_dir: str | None = None) -> RegionSamples:
    """Run the particle estimator (``particles`` per world set, the fitted terms off: :data:`OFF`) on
    ``scenarios`` (default every built-in one) x ``seeds`` and gather the hidden samples
    (:class:`RegionSamples`). ``workers`` processes; the result does not depend on their number.

    ``parts_dir``: each trial's samples are also written there (``<scenario>__s<seed>__K<k>.npz``) as
    the trial ends, and trials whose file is already there are read back, not run: an interrupted
    collection keeps what it had done."""
    import os

    from experiments.scenarios import list_scenarios, resolve_scenarios

    names = resolve_scenarios(list(scenarios)) if scenarios else list_scenarios()  # checked before anything runs
    jobs = [(name, int(seed), particles) for name in names for seed in seeds]
    parts: dict[tuple, tuple] = {}
    if parts_dir is not None:
        os.makedirs(parts_dir, exist_ok=True)
        for job in jobs:
            path = _part_path(parts_dir, job)
            if os.path.exists(path):
                parts[job] = _read_part(path)
    todo = [j for j in jobs if j not in parts]

    def keep(job, part):
        parts[job] = part
        if parts_dir is not None:
            _write_part(_part_path(parts_dir, job), part)

    if workers > 1 and todo:
        from experiments.evaluation.sweep import spawn_pool
        with spawn_pool(workers) as pool:
            for job, part in zip(todo, pool.imap(_trial_samples, todo, chunksize=1)):
                keep(job, part)
    else:
        for job in todo:
            keep(job, _trial_samples(job))
    res, cov, spd, scen = [], [], [], []
    trial = []
    for i, job in enumerate(jobs):
        r, c, s = parts[job]
        res.append(r)
        cov.append(c)
        spd.append(s)
        scen.append(np.full(len(r), names.index(job[0])))
        trial.append(np.full(len(r), i))
    return RegionSamples(np.concatenate(res).reshape(-1, 3), np.concatenate(cov).reshape(-1, 3, 3),
                         np.concatenate(spd), np.concatenate(scen).astype(int), tuple(names),
                         np.concatenate(trial).astype(int))


def _part_path(parts_dir: str, job: tuple[str, int, int]) -> str:
    import os

    name, seed, particles = job
    return os.path.join(parts_dir, f"{name}__s{seed}__K{particles}.npz")


def _write_part(path: str, part: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """One trial's samples (see :func:`collect_region_samples`)."""
    _save_npz(path, residual=part[0], cov=part[1], speed=part[2])


def _read_part(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    z = _load_npz(path, ("residual", "cov", "speed"),
                  "not a trial's region samples; delete it to run the trial again")
    return z["residual"], z["cov"], z["speed"]


def _trial_samples(job: tuple[str, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hidden samples of one trial (a scenario, a seed, a particle count)."""
    from estimator.observations import parse_frame
    from experiments.evaluation.methods import run_method
    from experiments.evaluation.scoring import position_arrays
    from experiments.evaluation.trials import _simulation, trial_rng

    name, seed, particles = job
    sim = _simulation(name, seed, None)
    scene = sim.scene
    frames = [parse_frame(f, known_ids=scene.object_ids) for f in sim.observations]
    run = run_method("particles", scene, frames, particles, trial_rng(seed, "particles"), config=json.dumps(OFF))
    est, cov, _dof, tru, vis, _held, _rows = position_arrays(scene, sim.truth, run.steps)
    T, D = vis.shape
    times = np.array([s.t for s in run.steps])
    speed = np.zeros((T, D))
    if T > 1:
        gaps = np.diff(times)[:, None]
        step = np.linalg.norm(est[1:] - est[:-1], axis=-1)
        speed[1:] = np.where(gaps > 0, step / np.where(gaps > 0, gaps, 1.0), 0.0)
    speed = np.where(np.isfinite(speed), speed, 0.0)
    keep = ~vis & np.isfinite(est).all(axis=-1)
    return tru[keep] - est[keep], cov[keep], speed[keep]


def region_coverage(samples: RegionSamples, floor_std: float, speed_time: float, dof: float,
                    score_floor_std: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Coverage of the :data:`LEVELS` regions: pooled ``(L,)`` and per scenario ``(S, L)`` (NaN for a
    scenario without samples), the covariance being the particles' + ``floor_std^2`` +
    ``(speed_time * speed)^2`` (+ ``score_floor_std^2``: the evaluation's floor, to score as it
    does; + :data:`RIDGE_STD` ^2) times I. Each trial's coverage (``samples.trial``) is averaged, per
    scenario and over all trials (the evaluation's figures)."""
    var = floor_std ** 2 + score_floor_std ** 2 + RIDGE_STD ** 2 + (speed_time * samples.speed) ** 2
    r = samples.residual
    m2 = M.mahalanobis_sq(np.zeros_like(r), samples.cov + var[:, None, None] * np.eye(3), r, floor_std=0.0)
    inside = M.in_regions(m2, LEVELS, dof).astype(float)
    # one row per trial: its coverage and its scenario
    trials, idx = np.unique(samples.trial, return_inverse=True)
    counts = np.bincount(idx, minlength=len(trials)).astype(float)
    inside = np.stack([np.bincount(idx, weights=inside[:, j], minlength=len(trials)) for j in
                       range(len(LEVELS))], axis=1) / counts[:, None]
    scenario = np.zeros(len(trials), dtype=int)
    scenario[idx] = samples.scenario
    pooled = inside.mean(axis=0) if len(m2) else np.full(len(LEVELS), np.nan)
    per = np.full((len(samples.scenarios), len(LEVELS)), np.nan)
    for s in range(len(samples.scenarios)):
        mask = scenario == s
        if mask.any():
            per[s] = inside[mask].mean(axis=0)
    return pooled, per


def fit_regions(samples: RegionSamples, floors=FLOORS, speed_times=SPEED_TIMES, dofs=DOFS,
                min_scenario: float = 0.8, score_floor_std: float = 0.0) -> dict:
    """The grid point nearest to the target coverages (module docstring), scored with
    ``score_floor_std`` (m) added. Returns ``{"covariance_floor_std", "covariance_speed_time",
    "position_dof", "coverage": {"50", "90"}, "scenario_coverage": {name: [c50, c90]},
    "min_scenario_met": bool, "samples": N, "before": {"50", "90"}, "as_evaluated": {"50", "90",
    "min_scenario_90"}}``, ``before`` being the coverage with the terms off (Gaussian, no floor, no
    speed term) and ``as_evaluated`` the fit's with the evaluation's floor added
    (:data:`~experiments.evaluation.metrics.COV_FLOOR_STD`)."""
    if len(samples.residual) == 0:
        raise ValueError("fit_regions: no hidden samples (no scenario hides an object?)")
    best, best_any = None, None
    for f, c, nu in itertools.product(floors, speed_times, dofs):
        pooled, per = region_coverage(samples, f, c, nu, score_floor_std)
        loss = float(np.sum((pooled - np.asarray(LEVELS)) ** 2))
        ok = bool(np.all(np.nan_to_num(per[:, -1], nan=1.0) >= min_scenario))
        cand = (loss, f, c, nu, pooled, per)
        if best_any is None or loss < best_any[0]:
            best_any = cand
        if ok and (best is None or loss < best[0]):
            best = cand
    met = best is not None
    loss, f, c, nu, pooled, per = best if met else best_any
    before, _ = region_coverage(samples, 0.0, 0.0, math.inf, score_floor_std)
    seen, seen_per = region_coverage(samples, f, c, nu, M.COV_FLOOR_STD)
    return {"covariance_floor_std": f, "covariance_speed_time": c, "position_dof": None if math.isinf(nu) else nu,
            "coverage": {"50": round(float(pooled[0]), 3), "90": round(float(pooled[1]), 3)},
            "scenario_coverage": {name: [None if np.isnan(v) else round(float(v), 3) for v in per[s]]
                                  for s, name in enumerate(samples.scenarios)},
            "min_scenario_met": met, "samples": int(len(samples.residual)),
            "before": {"50": round(float(before[0]), 3), "90": round(float(before[1]), 3)},
            "as_evaluated": {"50": round(float(seen[0]), 3), "90": round(float(seen[1]), 3),
                             "min_scenario_90": round(float(np.nanmin(seen_per[:, -1])), 3)}}


def region_config(fit: dict) -> dict:
    """The ``--config`` JSON fragment that applies a :func:`fit_regions` result."""
    return {"noise": {k: fit[k] for k in ("covariance_floor_std", "covariance_speed_time", "position_dof")}}


__all__ = ["RegionSamples", "collect_region_samples", "region_coverage", "fit_regions", "region_config",
           "FLOORS", "SPEED_TIMES", "DOFS", "LEVELS", "OFF"]
