"""Timing the estimator against bare pybullet stepping of the same worlds, measured in the same run
(:func:`time_stream`); ``scene-estimator bench`` (:mod:`experiments.cli.bench`) prints its figures.

After each reasoning step that simulated, in the same worker processes, the same worlds are stepped
bare (``stepSimulation``, nothing else) for the same number of steps; their states are saved before
and restored after, untimed, so that load on the machine weighs on both alike. Reported: the median
and 95th percentile update time, the bare time, their ratio, updates per second, the time to build
the estimator (worlds and workers) and the peak summed resident memory of the process and its
workers; and where the update's time goes (medians over the timed updates): the main process's own
work, the slowest shard in its worker, the exchange (the rest of the pool call: waiting for the
slowest shard, messages, shared arrays), and each worker's time over its bare stepping per particle.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from typing import Iterable

import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig, with_adaptive_count
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from physics.scene import Scene


def _rss_mb(pids) -> float:
    try:
        import psutil
    except ImportError:  # pragma: no cover
        import resource
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    total = 0.0
    for pid in pids:
        try:
            total += psutil.Process(pid).memory_info().rss
        except psutil.Error:
            pass
    return total / 2**20


@dataclasses.dataclass
class StreamTiming:
    """What :func:`time_stream` measured (seconds). The per-update lists hold the timed reasoning
    steps: those after the warm-up that simulated (the first reasoning step only places the objects)."""

    startup_s: float
    time_step: float  # the physics time step (s): the stream time of a step
    peak_memory_mb: float = 0.0
    processing_s: float = 0.0  # every update() call, frames between reasoning steps included
    frame_times: list[float] = dataclasses.field(default_factory=list)
    update_s: list[float] = dataclasses.field(default_factory=list)
    update_t: list[float] = dataclasses.field(default_factory=list)  # the stream time (s) of each timed update
    bare_s: list[float] = dataclasses.field(default_factory=list)
    particles: list[int] = dataclasses.field(default_factory=list)  # K of each timed update
    steps: list[int] = dataclasses.field(default_factory=list)
    main_s: list[float] = dataclasses.field(default_factory=list)
    exchange_s: list[float] = dataclasses.field(default_factory=list)
    shard_s: list[float] = dataclasses.field(default_factory=list)
    over_s: list[float] = dataclasses.field(default_factory=list)
    parts_s: list[dict] = dataclasses.field(default_factory=list)  # the scene model's parts, per update
    resting_s: list[tuple[float, float]] = dataclasses.field(default_factory=list)  # see time_stream
    shard_parts_s: list[dict] = dataclasses.field(default_factory=list)  # the slowest shard's parts, per update
    step_mean_s: list[float] = dataclasses.field(default_factory=list)  # the workers' mean Bullet steps, per update
    per_particle: list[tuple[float, float, float, float]] = dataclasses.field(default_factory=list)  # objects moved, moving, frozen, slept early

    @property
    def stream_s(self) -> float:
        """Duration of the stream fed: from the first frame to the last, plus one frame period."""
        t = np.asarray(self.frame_times)
        return float(t[-1] - t[0] + np.median(np.diff(t))) if len(t) > 1 else 0.0


def time_stream(scene: Scene, cfg: EstimatorConfig, frames: Iterable[Frame], rng: np.random.Generator,
                warmup: int = 0, max_updates: int | None = None, resting: bool = False) -> StreamTiming:
    """Build a :class:`SceneEstimator` (timed) and feed it ``frames`` (each ``update`` timed). After each
    reasoning step that simulated, the same worlds are stepped bare as many steps as it simulated
    (saved before and restored after, untimed). The first ``warmup`` reasoning steps are not recorded;
    it stops after ``max_updates`` recorded ones. Memory is sampled after construction and after every
    update. ``resting``: the worlds are also stepped bare with their objects at rest out of collision
    (:meth:`~estimator.worlds.pool.WorldPool.bare_step`), and ``resting_s`` gets the slowest shard's
    stepping time with and without them, per update.

    Saving and restoring puts every position and velocity back, but not all of Bullet's state (its
    contacts' warm start, its sleep timers): the run goes on from worlds a little different from
    those of a run that is not timed, as a run on another machine would."""
    t0 = time.perf_counter()
    est = SceneEstimator(scene, cfg, rng)
    st = StreamTiming(startup_s=time.perf_counter() - t0, time_step=cfg.physics.time_step)
    with est:
        pool = est.pool
        pids = [os.getpid()] + pool.worker_pids()
        st.peak_memory_mb = _rss_mb(pids)
        t_tick, reasoning = None, 0
        for frame in frames:
            before = dict(est.model.seconds)
            t0 = time.perf_counter()
            belief = est.update(frame)
            dt = time.perf_counter() - t0
            st.processing_s += dt
            st.frame_times.append(frame.t)
            # the steps this update simulated: the filter steps from one reasoning frame to the next
            n_steps = 0
            if belief is not None:
                n_steps = 0 if t_tick is None else int(round((frame.t - t_tick) / cfg.physics.time_step))
                t_tick = frame.t
                reasoning += 1
            if n_steps > 0:
                run_s, worker_s = pool.last_run_seconds, list(pool.last_worker_seconds)
                shard_parts = dict(pool.last_worker_parts[int(np.argmax(worker_s))]) if pool.last_worker_parts else {}
                sizes = pool.shard_sizes  # the particles in use (they change with an adaptive count)
                # right after the update, so that load on the machine affects both alike: the same
                # worlds, the same number of steps, nothing else; then the worlds are put back
                pool.save()
                t0 = time.perf_counter()
                pool.bare_step(n_steps)
                dt_bare = time.perf_counter() - t0
                bare_worker_s = list(pool.last_worker_seconds)
                pool.restore()
                if resting:
                    pool.save()
                    pool.bare_step(n_steps, resting=False)
                    rest_worker_s = list(pool.last_worker_seconds)
                    pool.restore()
                if reasoning > warmup:
                    if resting:
                        st.resting_s.append((max(bare_worker_s), max(rest_worker_s)))
                    st.update_s.append(dt)
                    st.update_t.append(frame.t)
                    st.bare_s.append(dt_bare)
                    st.steps.append(n_steps)
                    st.main_s.append(dt - run_s)
                    st.exchange_s.append(run_s - max(worker_s))
                    st.shard_s.append(max(worker_s))
                    st.over_s.append(float(np.mean([(w - b) / n for w, b, n
                                                    in zip(worker_s, bare_worker_s, sizes) if n > 0])))
                    st.particles.append(est.K)
                    st.parts_s.append({k: v - before.get(k, 0.0) for k, v in est.model.seconds.items()})
                    st.shard_parts_s.append(shard_parts)
                    st.step_mean_s.append(float(np.mean([p.get("step", 0.0) for p in pool.last_worker_parts]))
                                          if pool.last_worker_parts else math.nan)
                    counts = {k: sum(c.get(k, 0) for c in pool.last_worker_counts)
                              for k in ("entries", "moved", "moving", "frozen", "slept early")}
                    if counts["entries"]:
                        n = est.K
                        st.per_particle.append((counts["moved"] / n, counts["moving"] / n, counts["frozen"] / n,
                                                counts["slept early"] / n))
            st.peak_memory_mb = max(st.peak_memory_mb, _rss_mb(pids))
            if max_updates is not None and len(st.update_s) >= max_updates:
                break
    if not st.update_s:
        raise ValueError("no reasoning step to time: the stream is shorter than two reasoning horizons")
    return st


def timing_row(st: StreamTiming) -> dict:
    """The figures of one measurement (times in ms unless named ``_s``)."""
    med, bare_med = float(np.median(st.update_s)), float(np.median(st.bare_s))
    parts = model_parts_ms(st.parts_s)
    shard_parts = model_parts_ms(st.shard_parts_s)
    stepped = sum(p.get("step", 0.0) for p in st.shard_parts_s)  # the slowest shard's Bullet steps
    main, exchange = float(np.median(st.main_s)), float(np.median(st.exchange_s))
    read_load = 1e-3 * (shard_parts.get("read", 0.0) + shard_parts.get("load", 0.0))
    floor = update_floors(st)
    return {"updates": len(st.update_s), "steps_per_update": int(np.median(st.steps)),
            "update_ms_median": 1e3 * med, "update_ms_p95": 1e3 * float(np.percentile(st.update_s, 95)),
            "bare_step_ms_median": 1e3 * bare_med, "ratio": med / bare_med, "updates_per_s": 1.0 / med,
            "startup_s": st.startup_s, "peak_memory_mb": st.peak_memory_mb,
            "main_ms_median": 1e3 * main, "exchange_ms_median": 1e3 * exchange,
            "slowest_shard_ms_median": 1e3 * float(np.median(st.shard_s)),
            "worker_overhead_us_per_particle": 1e6 * float(np.median(st.over_s)),
            "model_parts_ms_median": parts, "model_parts_slowest": slowest_parts(parts),
            "shard_parts_ms_median": shard_parts, "shard_parts": slowest_parts(shard_parts, len(shard_parts)),
            # the stream time the timed updates simulated over the slowest shard's Bullet steps in
            # them: the real-time factor with no work around the physics (an upper bound on what
            # cutting that work can reach; below 1, Bullet alone cannot keep up on this machine)
            "steps_bound_factor": sum(st.steps) * st.time_step / stepped if stepped > 0 else math.nan,
            # lower bounds on ``ratio`` that no cut of the workers' other work can pass (sums of the
            # medians): the main process's part and the exchange, which do not overlap the workers',
            # over bare stepping; then also the slowest shard's read and loads, which any filter of
            # simulated worlds must do
            "ratio_floor_main": (main + exchange + bare_med) / bare_med,
            "ratio_floor_read_load": (main + exchange + bare_med + read_load) / bare_med,
            # the update's time with nothing in the workers but the Bullet steps it took, spread
            # evenly over them: per update, main process + exchange + the workers' mean stepping
            # time; its median and 95th percentile bound the update's from below
            **update_floors_ms(floor),
            # the timed updates one by one (``--json`` only): which ones make the p95
            "per_update": per_update(st, floor),
            **({"mean_particles": float(np.mean(st.particles)), "max_particles": int(np.max(st.particles))}
               if st.particles else {}),
            # dynamic objects per particle the update moved (loaded awake, held, pushed out), and
            # those not at rest at its end, and those frozen (out of collision) while it stepped
            # (medians over the updates)
            **{name: float(np.median([m[j] for m in st.per_particle])) if st.per_particle else math.nan
               for j, name in enumerate(("moved_per_particle", "moving_per_particle", "frozen_per_particle"))},
            # ... and those put to sleep a few steps into the update (the mean: most updates have none)
            "slept_early_per_particle": float(np.mean([m[3] for m in st.per_particle])) if st.per_particle else math.nan,
            # the share of bare stepping that objects at rest cost (NaN where not measured)
            "resting_share": float(np.median([1.0 - r / b for b, r in st.resting_s])) if st.resting_s else math.nan}


def update_floors(st: StreamTiming) -> np.ndarray:
    """Per timed update (s): the main process's part plus the exchange plus the mean over the workers
    of their Bullet stepping time; ``(n,)``, NaN where the workers reported no step times. No cut of
    the work around the physics, and no balancing of the particles across the workers, makes an
    update faster than this: only cheaper or fewer Bullet steps."""
    n = len(st.update_s)
    if len(st.step_mean_s) != n or len(st.main_s) != n or len(st.exchange_s) != n:
        return np.full(n, math.nan)
    return np.add(np.add(st.main_s, st.exchange_s), st.step_mean_s)


def update_floors_ms(floor: np.ndarray) -> dict[str, float]:
    """``update_floor_ms_median`` and ``update_floor_ms_p95`` (ms): the median and 95th percentile of
    the per-update floors ``floor (n,)`` s (:func:`update_floors`; NaN when none is known); they
    bound the update's median and p95 from below."""
    if np.all(np.isnan(floor)):
        return {"update_floor_ms_median": math.nan, "update_floor_ms_p95": math.nan}
    return {"update_floor_ms_median": 1e3 * float(np.nanmedian(floor)),
            "update_floor_ms_p95": 1e3 * float(np.nanpercentile(floor, 95))}


def per_update(st: StreamTiming, floor: np.ndarray) -> dict[str, list]:
    """The timed updates one by one: ``t`` (s, the stream time of the frame that ran each),
    ``update_ms``, ``floor_ms`` (``floor (n,)`` s, :func:`update_floors`), ``bare_ms`` and
    ``particles``; times rounded to 0.01 ms."""
    def ms(xs):
        return [round(1e3 * float(x), 2) for x in xs]
    return {"t": [round(float(t), 4) for t in st.update_t], "update_ms": ms(st.update_s),
            "floor_ms": ms(floor), "bare_ms": ms(st.bare_s), "particles": [int(k) for k in st.particles]}


def bench_config(k: int | str, workers: int, config: EstimatorConfig | None = None) -> EstimatorConfig:
    """``config`` (default: the particle filter's defaults) with ``k`` particles and ``workers``;
    ``k = "auto"``: the adaptive count within the configuration's bounds, from its minimum."""
    cfg = dataclasses.replace(config or EstimatorConfig(noise=NoiseConfig()), workers=workers)
    if k == "auto":
        return with_adaptive_count(dataclasses.replace(cfg, particles=cfg.adaptive.min_particles))
    return dataclasses.replace(cfg, particles=k)


# (key, table heading, format) of the table's columns
SYNTHETIC_COLUMNS = [("particles", "K", "{}"), ("objects", "objects", "{}")]
TIMING_COLUMNS = [("update_ms_median", "median (ms)", "{:.1f}"), ("update_ms_p95", "p95 (ms)", "{:.1f}"),
                  ("bare_step_ms_median", "bare stepping (ms)", "{:.1f}"), ("ratio", "ratio", "{:.2f}")]
RESOURCE_COLUMNS = [("startup_s", "startup (s)", "{:.2f}"), ("peak_memory_mb", "peak memory (MB)", "{:.0f}")]
def model_parts_ms(parts: list[dict]) -> dict[str, float]:
    """The median time (ms) per update of each part over the timed updates ``parts`` (seconds per
    part, one dict per update), the slowest first: the scene model's parts (its mechanisms' hooks,
    ``settle``, ``weigh``, ``commit``: :attr:`~estimator.model.SceneModel.seconds`) or the slowest
    shard's (:attr:`~estimator.worlds.pool.WorldPool.last_worker_parts`)."""
    names = {k for p in parts for k in p}
    med = {k: 1e3 * float(np.median([p.get(k, 0.0) for p in parts])) for k in names}
    return dict(sorted(med.items(), key=lambda kv: (-kv[1], kv[0])))


def slowest_parts(parts_ms: dict[str, float], n: int = 3) -> str:
    """The ``n`` slowest parts of :func:`model_parts_ms`, as ``"name ms, ..."``."""
    return ", ".join(f"{k} {v:.1f}" for k, v in list(parts_ms.items())[:n])


BREAKDOWN_COLUMNS = [("steps_bound_factor", "real-time factor of Bullet's steps alone", "{:.2f}"),
                     ("ratio_floor_main", "ratio floor: main process", "{:.2f}"),
                     ("ratio_floor_read_load", "ratio floor: + read, load", "{:.2f}"),
                     ("update_floor_ms_median", "update floor: median (ms)", "{:.1f}"),
                     ("update_floor_ms_p95", "update floor: p95 (ms)", "{:.1f}"),
                     ("main_ms_median", "main process (ms)", "{:.2f}"),
                     ("slowest_shard_ms_median", "slowest shard (ms)", "{:.1f}"),
                     ("exchange_ms_median", "exchange (ms)", "{:.2f}"),
                     ("worker_overhead_us_per_particle", "worker over bare (us/particle)", "{:.0f}"),
                     ("resting_share", "resting share of bare", "{:.2f}"),
                     ("moved_per_particle", "objects moved per particle", "{:.2f}"),
                     ("moving_per_particle", "moving at the end per particle", "{:.2f}"),
                     ("frozen_per_particle", "frozen per particle", "{:.2f}"),
                     ("slept_early_per_particle", "slept early per particle (mean)", "{:.2f}"),
                     ("model_parts_slowest", "slowest model parts (ms)", "{}"),
                     ("shard_parts", "slowest shard's parts (ms)", "{}")]
