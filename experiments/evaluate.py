"""Statistical evaluation: trials, sweeps, backends, resumable results and the summary.

A *trial* is one (scenario, seed, method, K): simulate the scenario's seeded variant
(:func:`experiments.simulator.simulate`), run the method on its perception stream
(:func:`experiments.methods.run_method`), score the run against the ground truth
(:mod:`experiments.metrics`) and return one flat JSON row. A row depends only on the trial's key and
the code: its random generator is seeded from (seed, method) with :class:`numpy.random.SeedSequence`,
every method runs its worlds inside the trial's process, and wall-clock measurements live in the row's
``"timing"`` sub-dict, apart from the deterministic fields.

A *sweep* runs every trial of a :class:`SweepConfig` that is not already in ``OUT/trials.jsonl``,
on a local process pool (``backend="local"``, spawned processes) or as Ray tasks
(``backend="ray"``; ``address`` joins an existing cluster), appends one line per finished trial
(flushed at once; an interrupted sweep loses at most the trials in flight, and a line cut in the
middle is dropped on the next run), shows a progress bar with an ETA on stderr, and finally writes
``summary.md``, ``summary.csv`` and PNG figures into ``OUT``. The per-scenario figures need a trace
(estimates over time, particle cloud) of one seed per scenario and method; traces are written to
``OUT/traces/`` by the trials of ``SweepConfig.trace_seeds``.
"""
from __future__ import annotations

import concurrent.futures as cf
import csv
import functools
import io
import json
import math
import multiprocessing
import os
import resource
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from scipy.stats import chi2

from . import metrics as M
from .methods import METHODS, MethodRun, effective_particles, get_method, run_method
from .stats import bootstrap_ci, group_rng, paired_wilcoxon

ROW_VERSION = 1
TRIALS_FILE = "trials.jsonl"
LOOSE_EVENT_WINDOW = 1.5
"""A second, looser event-matching window (s): the paper's reasoner only notices that a vanished
object was released after its 0.7 s perception timeout, later than the 0.5 s window."""


# --------------------------------------------------------------------------------------------------
# trial specification


@dataclass(frozen=True)
class TrialSpec:
    """One trial. ``particles`` is the method's effective K (0 for last-seen, 1 for paper);
    ``duration`` (s) overrides the scenario's; ``trace`` asks for the data of the per-scenario
    figures; ``rerun_dir`` records the trial as ``<rerun_dir>/<key>.rrd``; ``config`` is estimator
    configuration data (canonical JSON, see :mod:`estimator.config`) applied on top of the method's
    own configuration."""

    scenario: str
    seed: int
    method: str
    particles: int
    duration: float | None = None
    trace: bool = False
    rerun_dir: str | None = None
    config: str | None = None

    @property
    def key(self) -> str:
        """Identity of the trial in ``trials.jsonl`` (also a safe file name)."""
        d = "full" if self.duration is None else f"{self.duration:g}s"
        key = f"{self.scenario}__s{self.seed}__{self.method}__K{self.particles}__{d}"
        if self.config is not None:
            key += f"__cfg{zlib.crc32(self.config.encode()):08x}"
        return key


def trial_rng(seed: int, method: str) -> np.random.Generator:
    """The trial's only random generator, from (seed, method): independent across methods, the same
    on every backend and in every process."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(method.encode())]))


# --------------------------------------------------------------------------------------------------
# scoring a run


def _dynamic(scene) -> list[int]:
    return [i for i, o in enumerate(scene.objects) if not o.static]


def _truth_rows_at(truth: list[dict], times: list[float]) -> list[dict]:
    """The truth row at (or, failing an exact match, last before) each time."""
    tt = np.array([r["t"] for r in truth])
    out = []
    for t in times:
        j = int(np.searchsorted(tt, t + 1e-6, side="right")) - 1
        out.append(truth[max(j, 0)])
    return out


def score_run(scene, truth: list[dict], true_events: list[dict], run: MethodRun, frames=None) -> dict:
    """Metrics of one method run against the ground truth (a flat dict plus ``"reliability"``).

    Args:
        scene: the scene the method ran on (object order of the arrays).
        truth: truth rows (one per camera frame) of :class:`~experiments.simulator.SimulationResult`.
        true_events: the true events ``[{"t", "action", "subject"}]``.
        run: the method's steps and events.
        frames: the perception frames the method ran on; when given, the re-appearance and NEES
            metrics of :mod:`experiments.tracking_metrics` are added.

    Objects scored: the dynamic (non-static) objects. Samples: every (reasoning step, object).
    """
    ids = list(scene.object_ids)
    dyn = _dynamic(scene)
    dyn_ids = [ids[i] for i in dyn]
    names = ids + ["floor"]
    steps = run.steps
    T, D, Mo = len(steps), len(dyn), len(ids)
    rows = _truth_rows_at(truth, [s.t for s in steps])
    est = np.array([s.positions[dyn] for s in steps]).reshape(T, D, 3)
    cov = np.array([s.covariances[dyn] for s in steps]).reshape(T, D, 3, 3)
    p_pl = np.array([s.p_plausible[dyn] for s in steps]).reshape(T, D)
    tru = np.array([[r["objects"][o]["position"] for o in dyn_ids] for r in rows]).reshape(T, D, 3)
    vis = np.array([[r["objects"][o]["visible"] for o in dyn_ids] for r in rows], bool).reshape(T, D)
    held = np.array([[r["objects"][o]["held"] for o in dyn_ids] for r in rows], bool).reshape(T, D)

    # relations as (T, D, Mo + 1) / (T, D, Mo) arrays of probabilities and truths
    col = {n: j for j, n in enumerate(names)}
    sub = {o: k for k, o in enumerate(dyn_ids)}

    def fill(rel_dicts, predicate, width):
        a = np.zeros((T, D, width))
        for t_i, rels in enumerate(rel_dicts):
            for (s, p, o), prob in rels.items():
                if p == predicate and s in sub and o in col and col[o] < width:
                    a[t_i, sub[s], col[o]] = prob
        return a

    def truth_dict(r):
        return {(x["subject"], x["predicate"], x["object"]): float(x.get("p", 1.0)) for x in r["relations"]}

    est_rels = [s.relations for s in steps]
    tru_rels = [truth_dict(r) for r in rows]
    pair_on = np.ones((D, Mo + 1), bool)
    pair_in = np.ones((D, Mo), bool)
    for k, i in enumerate(dyn):
        pair_on[k, i] = pair_in[k, i] = False
    p_on, y_on = fill(est_rels, "isOnTop", Mo + 1), fill(tru_rels, "isOnTop", Mo + 1) > 0.5
    p_in, y_in = fill(est_rels, "isIn", Mo), fill(tru_rels, "isIn", Mo) > 0.5
    p_on, y_on = p_on[:, pair_on], y_on[:, pair_on]
    p_in, y_in = p_in[:, pair_in], y_in[:, pair_in]

    out: dict = {"n_steps": T, "n_objects": D}
    err = M.position_errors(est, tru)
    hidden = ~vis
    q_all, q_hid = M.error_quantiles(err), M.error_quantiles(err, hidden)
    out.update(n_hidden=q_hid["n"], err_median=q_all["median"], err_p90=q_all["p90"],
               err_hidden_median=q_hid["median"], err_hidden_p90=q_hid["p90"])
    # the end of the run
    if T:
        end_err = err[-1]
        sup = [M.truth_supports(rows[-1]["relations"], o, bool(held[-1, k])) for k, o in enumerate(dyn_ids)]
        ok = np.array([M.success(end_err[k], steps[-1].top[i], sup[k]) for k, i in enumerate(dyn)])
        ever_hidden = hidden.any(axis=0)
        out.update(err_end_mean=float(np.mean(end_err)), err_end_max=float(np.max(end_err)),
                   success_end=float(np.mean(ok)),
                   success_end_hidden=float(np.mean(ok[ever_hidden])) if ever_hidden.any() else math.nan)
    else:
        out.update(err_end_mean=math.nan, err_end_max=math.nan, success_end=math.nan,
                   success_end_hidden=math.nan)
    # relations over time
    for name, p, y in (("ontop", p_on, y_on), ("isin", p_in, y_in)):
        sc = M.binary_scores(p > 0.5, y)
        out[f"{name}_acc"], out[f"{name}_f1"] = sc["accuracy"], sc["f1"]
    # events
    ev = M.event_scores(run.events, true_events)
    out.update(event_precision=ev["precision"], event_recall=ev["recall"], event_f1=ev["f1"],
               event_latency=ev["latency_median"], events_true=ev["n_true"], events_est=ev["n_est"],
               events_matched=ev["n_matched"])
    loose = M.event_scores(run.events, true_events, window=LOOSE_EVENT_WINDOW)
    out.update(event_f1_loose=loose["f1"], event_latency_loose=loose["latency_median"])
    for action in ("Pick", "Place", "Release"):
        out[f"{action.lower()}_f1"] = M.event_scores(run.events, true_events, actions=(action,))["f1"]
    # calibration of the position
    ok = np.isfinite(est).all(axis=-1)
    nll = np.where(ok, M.gaussian_nll(np.where(ok[..., None], est, 0.0), cov, tru), np.nan)
    m2 = np.where(ok, M.mahalanobis_sq(np.where(ok[..., None], est, 0.0), cov, tru), np.nan)
    for suffix, mask in (("", ok), ("_hidden", ok & hidden)):
        v = nll[mask]
        out[f"nll{suffix}"] = float(np.mean(v)) if v.size else math.nan
        out[f"nll{suffix}_median"] = float(np.median(v)) if v.size else math.nan
        for level in (0.5, 0.9):
            out[f"cover{int(level * 100)}{suffix}"] = (float(np.mean(m2[mask] <= chi2.ppf(level, 3)))
                                                       if v.size else math.nan)
    # calibration of the probabilities
    rel = {}
    for name, p, y in (("plausible", p_pl.ravel(), ~held.ravel()), ("isIn", p_in.ravel(), y_in.ravel()),
                       ("isOnTop", p_on.ravel(), y_on.ravel())):
        out[f"brier_{name.lower()}"] = M.brier_score(p, y)
        bins = M.reliability_bins(p, y)
        out[f"ece_{name.lower()}"] = M.ece_from_bins(bins)
        rel[name] = bins
    out["reliability"] = rel
    if frames is not None:
        out.update(_tracking_scores(dyn_ids, truth, frames, steps, est, cov, tru, vis, run.gate_actions))
    return out


def _tracking_scores(dyn_ids, truth, frames, steps, est, cov, tru, vis, gate_actions=None) -> dict:
    """Re-appearance and NEES metrics (:mod:`experiments.tracking_metrics`) of a run; with the Kalman
    tracker's ``gate_actions`` (see :class:`~experiments.methods.MethodRun`), a re-appearance is
    inside the gate when the tracker accepted it."""
    from .tracking_metrics import nees_scores, reappearance_scores

    f_count, d_count = len(frames), len(dyn_ids)
    det_pos = np.full((f_count, d_count, 3), np.nan)
    det_std = np.full((f_count, d_count), np.nan)
    for i, f in enumerate(frames):
        for k, oid in enumerate(dyn_ids):
            d = f.objects.get(oid)
            if d is not None:
                det_pos[i, k] = d.position
                det_std[i, k] = np.nan if d.position_std is None else d.position_std
    det_t = np.array([f.t for f in frames])
    rows = _truth_rows_at(truth, list(det_t))
    true_pos = np.array([[r["objects"][o]["position"] for o in dyn_ids] for r in rows]).reshape(f_count, d_count, 3)
    accepted = None
    if gate_actions is not None:
        accepted = np.array([[gate_actions.get((i, oid)) == "accepted" for oid in dyn_ids] for i in range(f_count)],
                            dtype=bool).reshape(f_count, d_count)
    out = reappearance_scores(np.array([s.t for s in steps]), est, cov, det_t, det_pos, det_std, true_pos,
                              accepted=accepted)
    out.update(nees_scores(est, cov, tru, vis))
    return out


# --------------------------------------------------------------------------------------------------
# running a trial


@functools.lru_cache(maxsize=2)
def _simulation(scenario: str, seed: int, duration: float | None):
    from .simulator import simulate
    return simulate(scenario, seed, duration)


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
    dyn = _dynamic(scene)
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
        from .recording import Recorder
    except ImportError as exc:
        raise RuntimeError("--rerun-dir needs experiments.recording (rerun support), which is not "
                           f"available: {exc}") from exc
    os.makedirs(spec.rerun_dir, exist_ok=True)
    return Recorder(os.path.join(spec.rerun_dir, f"{spec.key}.rrd"), sim.scene)


def run_trial(spec: TrialSpec) -> dict:
    """Run one trial; returns ``{"row": row, "trace": trace or None}``.

    The row: ``key``, ``scenario``, ``seed``, ``method``, ``particles``, ``duration``, ``version``,
    the metrics of :func:`score_run`, and ``timing`` (wall clock, not reproducible):
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
    sim = _simulation(spec.scenario, spec.seed, spec.duration)
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
    try:
        run = run_method(spec.method, scene, frames, spec.particles, trial_rng(spec.seed, spec.method),
                         keep_particles=spec.trace, on_step=on_step, config=spec.config)
        if rec is not None:
            flush(math.inf)
            if run.events and hasattr(rec, "log_timeline"):
                rec.log_timeline({"t_end": run.steps[-1].t if run.steps else 0.0, "facts": [],
                                  "events": run.events})
    finally:
        if rec is not None:
            rec.close()
    scores = score_run(scene, sim.truth, sim.events, run, frames)
    ms = 1e3 * np.asarray(run.step_seconds)
    row = {"key": spec.key, "version": ROW_VERSION, "scenario": spec.scenario, "seed": spec.seed,
           "method": spec.method, "particles": spec.particles, "duration": spec.duration}
    if spec.config is not None:
        row["config"] = spec.config
    row.update(scores)
    row["timing"] = {"update_ms_median": float(np.median(ms)) if ms.size else None,
                     "update_ms_p95": float(np.percentile(ms, 95)) if ms.size else None,
                     "peak_rss_mb": _peak_rss_mb(), "rss_start_mb": rss_start, "peak_rss_per_trial": reset,
                     "trial_s": time.perf_counter() - t_start, "simulate_s": t_sim}
    return {"row": _clean(row), "trace": _trace(spec, sim, run) if spec.trace else None}


def run_trial_safe(spec: TrialSpec) -> dict:
    """:func:`run_trial`, but a failure is returned (``{"row": None, "key", "error"}``) instead of
    raised, so that one broken trial does not stop a sweep."""
    try:
        return run_trial(spec)
    except Exception:  # noqa: BLE001 - reported in errors.jsonl and retried by the next run
        import traceback
        return {"row": None, "trace": None, "key": spec.key, "error": traceback.format_exc()}


class TrialFailures(RuntimeError):
    """Some trials of a sweep raised; their tracebacks are in ``errors.jsonl``."""


def deterministic_part(row: dict) -> dict:
    """The row without its wall-clock ``timing``: what must agree across backends and reruns."""
    return {k: v for k, v in row.items() if k != "timing"}


# --------------------------------------------------------------------------------------------------
# sweeps


@dataclass(frozen=True)
class SweepConfig:
    """The trials of a sweep: every scenario x seed x method, each particle method once per K in
    ``particles`` (last-seen and paper once). ``trace_seeds``: seeds whose trials write traces for
    the per-scenario figures (default: the first seed). ``config``: estimator configuration data
    (canonical JSON) for the particle methods, on top of each one's own settings; last-seen and the
    paper's reasoner, the references, are left as they are."""

    scenarios: tuple[str, ...]
    seeds: tuple[int, ...]
    methods: tuple[str, ...]
    particles: tuple[int, ...] = (64,)
    duration: float | None = None
    trace_seeds: tuple[int, ...] | None = None
    config: str | None = None

    def __post_init__(self):
        if not self.scenarios or not self.seeds or not self.methods or not self.particles:
            raise ValueError("a sweep needs at least one scenario, seed, method and particle count")
        for m in self.methods:
            get_method(m)
        if any(k < 1 for k in self.particles):
            raise ValueError(f"particle counts must be >= 1, got {self.particles}")
        if self.duration is not None and not self.duration > 0:
            raise ValueError(f"duration must be > 0, got {self.duration}")

    def trials(self, rerun_dir: str | None = None) -> list[TrialSpec]:
        """The sweep's trials in canonical order (scenario, seed, method, K), without duplicates."""
        traces = set(self.trace_seeds if self.trace_seeds is not None else self.seeds[:1])
        out, seen = [], set()
        for sc in self.scenarios:
            for seed in self.seeds:
                for m in self.methods:
                    for k in self.particles:
                        cfg = self.config if get_method(m).uses_particles else None
                        spec = TrialSpec(sc, int(seed), m, effective_particles(m, k), self.duration,
                                         trace=seed in traces, rerun_dir=rerun_dir, config=cfg)
                        if spec.key not in seen:
                            seen.add(spec.key)
                            out.append(spec)
        return out


def read_rows(path: str | os.PathLike, repair: bool = False) -> list[dict]:
    """Rows of a ``trials.jsonl``. A last line cut short by an interruption is ignored (and, with
    ``repair``, removed from the file so that the next row starts on a fresh line); a malformed line
    elsewhere is an error. Later rows with the same key replace earlier ones."""
    p = Path(path)
    if not p.exists():
        return []
    data = p.read_bytes()
    lines = data.split(b"\n")
    rows: dict[str, dict] = {}
    good_end = 0
    pos = 0
    for i, line in enumerate(lines):
        end = pos + len(line) + 1
        if line.strip():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                if i < len(lines) - 1 and any(x.strip() for x in lines[i + 1:]):
                    raise ValueError(f"{p}: line {i + 1} is not valid JSON") from None
                break
            if i == len(lines) - 1:  # complete JSON but no newline: keep it, add the newline
                rows[row["key"]] = row
                good_end = len(data)
                break
            rows[row["key"]] = row
        good_end = min(end, len(data))
        pos = end
    if repair:
        with open(p, "r+b") as fh:
            fh.truncate(good_end)
            if good_end and not data[:good_end].endswith(b"\n"):
                fh.seek(0, 2)
                fh.write(b"\n")
    return list(rows.values())


class Progress:
    """A one-line progress bar with rate and ETA on a stream (stderr), e.g.
    ``[#####.....] 12/30 trials  1:02 elapsed  ETA 1:34``. Not a TTY: one line per 10 %."""

    def __init__(self, total: int, done: int = 0, stream=None, enabled: bool = True, label: str = "trials"):
        self.total, self.done, self.start_done = total, done, done
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.label = label
        self.t0 = time.monotonic()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last_decile = -1
        self.draw()

    @staticmethod
    def _fmt(s: float) -> str:
        s = int(round(s))
        h, rem = divmod(s, 3600)
        m, sec = divmod(rem, 60)
        return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"

    def text(self) -> str:
        width = 24
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(frac * width) + "." * (width - int(frac * width))
        elapsed = time.monotonic() - self.t0
        new = self.done - self.start_done
        eta = "--:--" if new == 0 else self._fmt(elapsed / new * (self.total - self.done))
        return (f"[{bar}] {self.done}/{self.total} {self.label}  {self._fmt(elapsed)} elapsed  "
                f"ETA {eta}")

    def draw(self) -> None:
        if not self.enabled:
            return
        if self.tty:
            self.stream.write("\r" + self.text())
            self.stream.flush()
            return
        decile = int(10 * self.done / self.total) if self.total else 10
        if decile != self._last_decile:
            self._last_decile = decile
            self.stream.write(self.text() + "\n")
            self.stream.flush()

    def update(self, n: int = 1) -> None:
        self.done += n
        self.draw()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _local_results(specs: list[TrialSpec], workers: int) -> Iterable[dict]:
    """Run trials in this process (``workers <= 1``) or on a pool of spawned processes; yields
    results as they finish. Pending trials are cancelled when the consumer stops."""
    if workers <= 1:
        for spec in specs:
            yield run_trial_safe(spec)
        return
    ctx = multiprocessing.get_context("spawn")
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=None)
    try:
        futures = [pool.submit(run_trial_safe, s) for s in specs]
        for fut in cf.as_completed(futures):
            yield fut.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _ray_results(specs: list[TrialSpec], workers: int, address: str | None,
                 init_kwargs: dict | None) -> Iterable[dict]:
    """Run trials as Ray tasks (one CPU each); yields results as they finish."""
    try:
        import ray
    except ImportError:
        raise RuntimeError("the ray backend needs Ray: pip install 'scene-estimator[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw = dict(init_kwargs or {})
        if address:
            kw["address"] = address
        else:
            kw.setdefault("num_cpus", max(workers, 1))
            kw.setdefault("include_dashboard", False)
        kw.setdefault("log_to_driver", False)
        ray.init(**kw)
        started = True
    remote = ray.remote(num_cpus=1, max_retries=1)(run_trial_safe)
    pending = [remote.remote(s) for s in specs]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                yield ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


def code_version() -> dict:
    """Git commit of the code and whether the working tree differs from it (best effort)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit or None, "dirty": bool(dirty) if commit else None}


def _log_run(path: Path, config: SweepConfig, backend: str, workers: int | None) -> None:
    """Append when, with which code and how a sweep was (re)started to ``runs.jsonl``: rows of a
    resumed sweep may come from several runs."""
    rec = {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **code_version(), "backend": backend,
           "workers": workers, "config": {k: (list(v) if isinstance(v, tuple) else v)
                                          for k, v in config.__dict__.items()}}
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(rec) + "\n")


def run_sweep(config: SweepConfig, out_dir: str | os.PathLike, *, backend: str = "local",
              workers: int | None = None, address: str | None = None, rerun_dir: str | None = None,
              progress: bool = True, ray_init: dict | None = None, report: bool = True,
              on_row: Callable[[dict], None] | None = None) -> list[dict]:
    """Run the trials of ``config`` missing from ``out_dir/trials.jsonl`` and write the summary.

    Args:
        backend: ``"local"`` (process pool; ``workers <= 1`` runs in this process) or ``"ray"``.
        workers: parallel trials (default: the number of CPUs; Ray: CPUs of the local cluster).
        address: Ray cluster to join (``"auto"``, ``"ray://host:10001"``...); default a local one.
        rerun_dir: record every trial there as ``<key>.rrd``.
        ray_init: extra keyword arguments of ``ray.init``.
        report: write ``summary.md``, ``summary.csv`` and the figures at the end.
        on_row: called with every newly finished row.

    Returns the rows of the sweep's trials in canonical order. Raises :class:`TrialFailures` at
    the end (after the summary of the others) when some trials raised; they are not written to
    ``trials.jsonl``, so the next run retries them.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / TRIALS_FILE
    specs = config.trials(rerun_dir)
    _log_run(out / "runs.jsonl", config, backend, workers)
    done = {r["key"]: r for r in read_rows(path, repair=True)}
    todo = [s for s in specs if s.key not in done]
    # longest first (particle trials), for a shorter tail
    todo.sort(key=lambda s: (-s.particles, s.scenario, s.seed, s.method))
    workers = workers if workers is not None else (os.cpu_count() or 1)
    bar = Progress(len(specs), len(specs) - len(todo), enabled=progress)
    failures: list[dict] = []
    if todo:
        if backend == "ray":
            results = _ray_results(todo, workers, address, ray_init)
        else:
            results = _local_results(todo, workers)
        with open(path, "a", encoding="utf-8") as fh:
            try:
                for res in results:
                    row = res["row"]
                    if row is None:
                        failures.append(res)
                        with open(out / "errors.jsonl", "a", encoding="utf-8") as ef:
                            ef.write(json.dumps({"key": res["key"], "error": res["error"]}) + "\n")
                        print(f"\ntrial {res['key']} failed:\n{res['error']}", file=sys.stderr)
                        bar.update()
                        continue
                    fh.write(json.dumps(row, allow_nan=False) + "\n")
                    fh.flush()
                    done[row["key"]] = row
                    if res.get("trace") is not None:
                        (out / "traces").mkdir(exist_ok=True)
                        with open(out / "traces" / f"{row['key']}.json", "w", encoding="utf-8") as tf:
                            json.dump(res["trace"], tf)
                    bar.update()
                    if on_row is not None:
                        on_row(row)
            finally:
                close = getattr(results, "close", None)
                if close is not None:
                    close()
                bar.close()
    rows = [done[s.key] for s in specs if s.key in done]
    if report and rows:
        write_report(rows, out)
    if failures:
        raise TrialFailures(f"{len(failures)} of {len(specs)} trial(s) failed (tracebacks in "
                            f"{out / 'errors.jsonl'}); the summary covers the others; run again to retry")
    return rows


# --------------------------------------------------------------------------------------------------
# the summary


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
    Column("pick_f1", "Pick F1"), Column("place_f1", "Place F1"), Column("release_f1", "Release F1"),
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
    Column("timing.update_ms_p95", "update p95 (ms)"), Column("timing.peak_rss_mb", "peak memory (MB)"),
    Column("timing.trial_s", "trial (s)"),
)

TEST_METRICS: tuple[tuple[str, str, float], ...] = (
    ("err_hidden_median", "hidden err. median (cm)", 100.0),
    ("err_end_mean", "final err. (cm)", 100.0),
    ("success_end", "success (%)", 100.0),
    ("event_f1", "event F1", 1.0),
)
"""Metrics of the paired tests (particle methods against the paper's reasoner, paired by seed)."""

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


def paired_tests(rows: list[dict], baseline: str = "paper") -> list[dict]:
    """Wilcoxon signed-rank tests of every particle method against ``baseline``, per scenario and
    over all scenarios, paired by (scenario, seed), for each of :data:`TEST_METRICS`."""
    base = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == baseline}
    if not base:
        return []
    out = []
    scenarios = sorted({r["scenario"] for r in rows})
    for m, k in _method_order(rows):
        if not get_method(m).uses_particles:
            continue
        mine = {(r["scenario"], r["seed"]): r for r in rows if r["method"] == m and r["particles"] == k}
        for sc in scenarios + ([ALL] if len(scenarios) > 1 else []):
            keys = sorted(x for x in mine if x in base and (sc == ALL or x[0] == sc))
            if not keys:
                continue
            rec = {"scenario": sc, "method": m, "particles": k, "baseline": baseline}
            for fieldname, _h, _s in TEST_METRICS:
                t = paired_wilcoxon([_value(mine[x], fieldname) for x in keys],
                                    [_value(base[x], fieldname) for x in keys])
                rec[fieldname + ".n"] = t.n
                rec[fieldname + ".median_diff"] = t.median_diff
                rec[fieldname + ".p"] = t.p_value
            out.append(rec)
    return out


def _cell(rec: dict, c: Column) -> str:
    v, lo, hi = rec.get(c.field), rec.get(c.field + ".lo"), rec.get(c.field + ".hi")
    if v is None or not math.isfinite(v):
        return "–"
    s = c.fmt.format(v * c.scale)
    if lo is not None and math.isfinite(lo):
        s += " [" + c.fmt.format(lo * c.scale) + ", " + c.fmt.format(hi * c.scale) + "]"
    return s


def _method_label(m: str, k: int) -> str:
    return f"{m} (K={k})" if get_method(m).uses_particles else m


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
        cells = [rec["scenario"], _method_label(rec["method"], rec["particles"]), str(rec["n"])]
        cells += [_cell(rec, c) for c in columns]
        buf.write("| " + " | ".join(cells) + " |\n")
    if tests:
        buf.write("\n## Paired tests against the paper's reasoner (Wilcoxon signed-rank, by seed)\n\n"
                  "Cells: median difference (method - paper) and two-sided p-value; n = pairs.\n\n")
        head = ["scenario", "method"] + [h for _f, h, _s in TEST_METRICS]
        buf.write("| " + " | ".join(head) + " |\n|" + "|".join(["---"] * len(head)) + "|\n")
        for t in tests:
            cells = [t["scenario"], _method_label(t["method"], t["particles"])]
            for f, _h, s in TEST_METRICS:
                d, p, n = t[f + ".median_diff"], t[f + ".p"], t[f + ".n"]
                cells.append("–" if not (n and math.isfinite(d)) else
                             f"{d * s:+.2f} (p={p:.3g}, n={n})" if math.isfinite(p) else f"{d * s:+.2f} (n={n})")
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
        cells = [_method_label(rec["method"], rec["particles"]) + ("" if rec["scenario"] == ALL else
                                                                   f" ({rec['scenario']})")]
        cells += [_cell(rec, c) if c.field in rec else "–" for c in calib]
        buf.write("| " + " | ".join(cells) + " |\n")
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


def write_report(rows: list[dict], out_dir: str | os.PathLike, plots: bool = True) -> dict[str, Path]:
    """Write ``summary.md``, ``summary.csv``, ``tests.csv`` and the figures for ``rows``; returns the
    paths."""
    out = Path(out_dir)
    summary = summarize(rows)
    tests = paired_tests(rows)
    paths = {"summary.md": out / "summary.md", "summary.csv": out / "summary.csv"}
    from .tracker_report import markdown_tracker_section
    paths["summary.md"].write_text(markdown_summary(summary, tests) + markdown_tracker_section(rows), encoding="utf-8")
    write_summary_csv(summary, paths["summary.csv"])
    if tests:
        paths["tests.csv"] = out / "tests.csv"
        write_summary_csv(tests, paths["tests.csv"])
    if plots:
        from .plots import make_figures
        for p in make_figures(rows, summary, out):
            paths[p.name] = p
    return paths
