"""One trial of the evaluation: (scenario, seed, method, K).

Simulate the scenario's seeded variant (:func:`experiments.simulation.simulator.simulate`), run the
method on its perception stream (:func:`experiments.evaluation.methods.run_method`), score the run
against the ground truth (:mod:`experiments.evaluation.scoring`) and return one flat JSON row. A row
depends only on the trial's key and the code: its random generator is seeded from (seed, method)
with :class:`numpy.random.SeedSequence`, every method runs its worlds inside the trial's process, and
wall-clock measurements live in the row's ``"timing"`` sub-dict, apart from the deterministic fields.
"""
from __future__ import annotations

import functools
import math
import os
import resource
import time
import zlib
from dataclasses import dataclass

import numpy as np

from experiments.evaluation.method_steps import MethodRun
from experiments.evaluation.methods import particles_label, run_method
from experiments.evaluation.scoring import dynamic_objects, score_run

ROW_VERSION = 1

# --------------------------------------------------------------------------------------------------
# trial specification


@dataclass(frozen=True)
class TrialSpec:
    """One trial. ``particles`` is the method's effective K (0 for last-seen, 1 for paper);
    ``duration`` (s) overrides the scenario's; ``trace`` asks for the data of the per-scenario
    figures; ``rerun_dir`` records the trial as ``<rerun_dir>/<key>.rrd``; ``config`` is estimator
    configuration data (canonical JSON, see :mod:`estimator.config`) applied on top of the method's
    own configuration; ``engine`` is the physics engine of the ground truth (``"bullet"`` or
    ``"mujoco"``, :data:`experiments.simulation.simulator.ENGINES`: the estimator is never told) and
    ``param_scale`` multiplies the truth's frictions and restitution against the nominal values the
    estimator's scene states."""

    scenario: str
    seed: int
    method: str
    particles: int
    duration: float | None = None
    trace: bool = False
    rerun_dir: str | None = None
    config: str | None = None
    engine: str = "bullet"
    param_scale: float = 1.0

    @property
    def key(self) -> str:
        """Identity of the trial in ``trials.jsonl`` (also a safe file name). The truth engine and the
        parameter scale appear only when they are not the defaults (Bullet, 1), so that the keys of
        rows written before they existed stay what they were."""
        d = "full" if self.duration is None else f"{self.duration:g}s"
        key = f"{self.scenario}__s{self.seed}__{self.method}__K{particles_label(self.particles)}__{d}"
        if self.config is not None:
            key += f"__cfg{zlib.crc32(self.config.encode()):08x}"
        if self.engine != "bullet":
            key += f"__{self.engine}"
        if self.param_scale != 1.0:
            key += f"__ps{self.param_scale:g}"
        return key


def trial_rng(seed: int, method: str) -> np.random.Generator:
    """The trial's only random generator, from (seed, method): independent across methods, the same
    on every backend and in every process."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(method.encode())]))


# --------------------------------------------------------------------------------------------------
# running a trial


@functools.lru_cache(maxsize=2)
def _simulation(scenario: str, seed: int, duration: float | None, engine: str = "bullet", param_scale: float = 1.0):
    from experiments.simulation.simulator import simulate
    if engine == "bullet" and param_scale == 1.0:
        return simulate(scenario, seed, duration)
    return simulate(scenario, seed, duration, engine=engine, param_scale=param_scale)


def _release_memory() -> None:
    """Give memory freed by earlier trials of this process back to the OS (glibc keeps it otherwise,
    and it would count in this trial's peak)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _status_mb(field: str) -> float:
    """A memory figure of this process from /proc/self/status (``VmRSS``, ``VmHWM``), in MB."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def _rss_mb() -> float:
    return _status_mb("VmRSS")


def _peak_rss_reset() -> bool:
    _release_memory()
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_rss_mb() -> float:
    peak = _status_mb("VmHWM")
    return peak if math.isfinite(peak) else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _clean(x):
    """JSON-safe copy: NaN / inf -> None, numpy scalars -> Python."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _trace(spec: TrialSpec, sim, run: MethodRun) -> dict:
    """Data of the per-scenario figures: estimates and their spread at every step, the truth and the
    perception at every frame, the particle cloud of the last step (positions rounded to 0.1 mm)."""
    scene = sim.scene
    ids = list(scene.object_ids)
    dyn = dynamic_objects(scene)
    dyn_ids = [ids[i] for i in dyn]

    def r(a):
        return np.round(np.asarray(a, float), 4).tolist()

    last = run.steps[-1] if run.steps else None
    obs = {o: [[f["t"], *f["objects"][o]["position"]] for f in sim.observations if o in f["objects"]]
           for o in dyn_ids}
    return _clean({
        "key": spec.key, "scenario": spec.scenario, "seed": spec.seed, "method": spec.method,
        "particles": spec.particles, "object_ids": dyn_ids,
        "t": [s.t for s in run.steps],
        "estimate": r([s.positions[dyn] for s in run.steps]),
        "std": r([np.sqrt(np.maximum(np.trace(s.covariances[dyn], axis1=-2, axis2=-1), 0.0))
                  for s in run.steps]),
        "truth_t": [row["t"] for row in sim.truth],
        "truth": r([[row["objects"][o]["position"] for o in dyn_ids] for row in sim.truth]),
        "visible": [[row["objects"][o]["visible"] for o in dyn_ids] for row in sim.truth],
        "observed": obs,
        "cloud": r(last.particles[:, dyn]) if last is not None and last.particles is not None else None,
        "cloud_weights": r(last.weights) if last is not None and last.weights is not None else None,
        "events_true": sim.events, "events_est": run.events,
    })


def _recorder_hook(spec: TrialSpec, sim):
    """A rerun recorder for the trial, or ``None`` (``--rerun-dir`` not given)."""
    if not spec.rerun_dir:
        return None
    try:
        from experiments.recording import Recorder
    except ImportError as exc:
        raise RuntimeError("--rerun-dir needs experiments.recording (rerun support), which is not "
                           f"available: {exc}") from exc
    os.makedirs(spec.rerun_dir, exist_ok=True)
    return Recorder(os.path.join(spec.rerun_dir, f"{spec.key}.rrd"), sim.scene)


class InvariantCount:
    """Counts, over a run's beliefs, the particle entries (update, particle, object) more than
    :data:`~physics.penetration.INVARIANT_DEPTH` inside static geometry or the floor (an impossible
    state; :class:`~physics.penetration.StaticGeometry`), and the deepest one. Beliefs without
    particles (last-seen, the tracker alone) are not counted."""

    def __init__(self, scene):
        from physics.penetration import StaticGeometry
        self.geometry = StaticGeometry(scene)
        self.updates = 0
        self.violations = 0
        self.deepest = 0.0

    def observe(self, belief) -> None:
        if belief is None or belief.particles is None:
            return
        from physics.penetration import INVARIANT_DEPTH
        known = np.array([oid in belief.objects for oid in belief.object_ids])
        d = self.geometry.depths(belief.particles, known)
        self.updates += 1
        self.violations += int((d > INVARIANT_DEPTH).sum())
        self.deepest = max(self.deepest, float(d.max(initial=0.0)))

    def fields(self) -> dict:
        """Row fields: ``invariant_violations`` (count), ``invariant_depth_max`` (m); None where no
        belief had particles."""
        if self.updates == 0:
            return {"invariant_violations": None, "invariant_depth_max": None}
        return {"invariant_violations": self.violations, "invariant_depth_max": self.deepest}

    def close(self) -> None:
        self.geometry.close()


def run_trial(spec: TrialSpec) -> dict:
    """Run one trial; returns ``{"row": row, "trace": trace or None}``.

    The row: ``key``, ``scenario``, ``seed``, ``method``, ``particles``, ``duration``, ``engine``,
    ``param_scale``, ``version``, the metrics of :func:`score_run`, the invariant's counts
    (:class:`InvariantCount`), and ``timing`` (wall clock, not reproducible):
    ``update_ms_median`` / ``update_ms_p95`` (per reasoning step), ``peak_rss_mb`` (peak resident
    memory of the process during the trial, after giving memory freed by earlier trials back to the
    OS; Linux. Where the peak cannot be reset, ``peak_rss_per_trial`` is false and it is the peak
    since the process started), ``rss_start_mb`` (resident memory at the start: the interpreter and
    its modules), ``trial_s`` and ``simulate_s``.
    """
    from estimator.observations import parse_frame

    reset = _peak_rss_reset()
    rss_start = _rss_mb()
    t_start = time.perf_counter()
    sim = _simulation(spec.scenario, spec.seed, spec.duration, spec.engine, spec.param_scale)
    t_sim = time.perf_counter() - t_start
    scene = sim.scene
    frames = [parse_frame(f, known_ids=scene.object_ids) for f in sim.observations]
    rec = _recorder_hook(spec, sim)
    on_step = None
    if rec is not None:
        pending = sorted([(f.t, 0, i) for i, f in enumerate(frames)]
                         + [(r["t"], 1, i) for i, r in enumerate(sim.truth)])

        def flush(until: float) -> None:  # frames and truth rows up to ``until``, in time order
            while pending and pending[0][0] <= until + 1e-9:
                _t, kind, i = pending.pop(0)
                if kind == 0:
                    rec.log_frame(frames[i])
                else:
                    rec.log_truth(sim.truth[i])

        def on_step(step, belief):
            flush(step.t)
            if belief is not None:
                rec.log_belief(belief)
    invariant = InvariantCount(scene)
    inner = on_step

    def on_step(step, belief):  # noqa: F811 - the recorder's hook (if any), then the invariant's
        if inner is not None:
            inner(step, belief)
        invariant.observe(belief)
    try:
        run = run_method(spec.method, scene, frames, spec.particles, trial_rng(spec.seed, spec.method),
                         keep_particles=spec.trace, on_step=on_step, config=spec.config)
        if rec is not None:
            flush(math.inf)
            if run.events and hasattr(rec, "log_timeline"):
                rec.log_timeline({"t_end": run.steps[-1].t if run.steps else 0.0, "facts": [],
                                  "events": run.events})
    finally:
        invariant.close()
        if rec is not None:
            rec.close()
    scores = score_run(scene, sim.truth, sim.events, run, frames)
    scores.update(invariant.fields())
    ms = 1e3 * np.asarray(run.step_seconds)
    row = {"key": spec.key, "version": ROW_VERSION, "scenario": spec.scenario, "seed": spec.seed,
           "method": spec.method, "particles": spec.particles, "duration": spec.duration,
           "engine": spec.engine, "param_scale": spec.param_scale}
    if spec.config is not None:
        row["config"] = spec.config
    row.update(scores)
    row["timing"] = {"update_ms_median": float(np.median(ms)) if ms.size else None,
                     "update_ms_p95": float(np.percentile(ms, 95)) if ms.size else None,
                     "peak_rss_mb": _peak_rss_mb(), "rss_start_mb": rss_start, "peak_rss_per_trial": reset,
                     "trial_s": time.perf_counter() - t_start, "simulate_s": t_sim}
    if run.mean_particles is not None:
        row["mean_particles"] = run.mean_particles
    return {"row": _clean(row), "trace": _trace(spec, sim, run) if spec.trace else None}


def run_trial_safe(spec: TrialSpec) -> dict:
    """:func:`run_trial`, but a failure is returned (``{"row": None, "key", "error"}``) instead of
    raised, so that one broken trial does not stop a sweep."""
    try:
        return run_trial(spec)
    except Exception:  # noqa: BLE001 - reported in errors.jsonl and retried by the next run
        import traceback
        return {"row": None, "trace": None, "key": spec.key, "error": traceback.format_exc()}


def deterministic_part(row: dict) -> dict:
    """The row without its wall-clock ``timing``: what must agree across backends and reruns."""
    return {k: v for k, v in row.items() if k != "timing"}
