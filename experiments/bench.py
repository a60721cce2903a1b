"""``scene-estimator bench``: update time of the estimator against bare pybullet stepping.

Two kinds of input, timed by the same loop (:func:`time_stream`):

* synthetic (``--objects``): for each particle count K and number of dynamic objects N (5 cm boxes
  resting on a table, perceived floating 1 cm with 3 mm noise), one frame per reasoning horizon
  (0.08 s, 19 steps), 3 untimed warm-up updates, then ``--updates`` timed ones;
* scenarios (``--scenario``, :mod:`experiments.bench_scenario`): the observation stream of a built-in
  simulated scenario (seed 0), every frame of it, so that the real-time factor can be read off.

After each reasoning step that simulated, in the same worker processes, the same worlds are stepped
bare (``stepSimulation``, nothing else) for the same number of steps; their states are saved before
and restored after, untimed, so that load on the machine weighs on both alike. Reported: the median
and 95th percentile update time, the bare time, their ratio, updates per second, the time to build
the estimator (worlds and workers) and the peak summed resident memory of the process and its
workers; with ``--breakdown``, where the update's time goes (medians over the timed updates): the
main process's own work, the slowest shard in its worker, the exchange (the rest of the pool call:
waiting for the slowest shard, messages, shared arrays), and each worker's time over its bare
stepping per particle.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from typing import Iterable

import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig, config_from_dict, read_config_file
from estimator.filter import SceneEstimator
from estimator.observations import Detection, Frame
from physics.scene import Scene, scene_from_dict

TABLE_TOP = 0.626


def bench_scene(n_objects: int) -> Scene:
    """A table with ``n_objects`` 5 cm boxes resting on it in a grid."""
    objs = [{"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
             "pose": {"position": [0, 0, 0]}}]
    for i in range(n_objects):
        x = -0.45 + 0.15 * (i % 7)
        y = -0.3 + 0.15 * (i // 7)
        objs.append({"id": f"box{i}", "box": {"size": [0.05, 0.05, 0.05]}, "mass": 0.1,
                     "pose": {"position": [x, y, TABLE_TOP + 0.025]}})
    return scene_from_dict({"name": f"bench_{n_objects}", "objects": objs})


def bench_frames(scene: Scene, n: int, horizon: float, rng: np.random.Generator):
    rest = {o.id: np.array(o.position) + [0, 0, 0.01] for o in scene.objects if not o.static}
    for k in range(n):
        yield Frame(k * horizon, {oid: Detection(p + rng.normal(0, 0.003, 3), np.array([0, 0, 0, 1.0]))
                                  for oid, p in rest.items()})


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
    peak_memory_mb: float = 0.0
    processing_s: float = 0.0  # every update() call, frames between reasoning steps included
    frame_times: list[float] = dataclasses.field(default_factory=list)
    update_s: list[float] = dataclasses.field(default_factory=list)
    bare_s: list[float] = dataclasses.field(default_factory=list)
    steps: list[int] = dataclasses.field(default_factory=list)
    main_s: list[float] = dataclasses.field(default_factory=list)
    exchange_s: list[float] = dataclasses.field(default_factory=list)
    shard_s: list[float] = dataclasses.field(default_factory=list)
    over_s: list[float] = dataclasses.field(default_factory=list)

    @property
    def stream_s(self) -> float:
        """Duration of the stream fed: from the first frame to the last, plus one frame period."""
        t = np.asarray(self.frame_times)
        return float(t[-1] - t[0] + np.median(np.diff(t))) if len(t) > 1 else 0.0


def time_stream(scene: Scene, cfg: EstimatorConfig, frames: Iterable[Frame], rng: np.random.Generator,
                warmup: int = 0, max_updates: int | None = None) -> StreamTiming:
    """Build a :class:`SceneEstimator` (timed) and feed it ``frames`` (each ``update`` timed). After each
    reasoning step that simulated, the same worlds are stepped bare as many steps as it simulated
    (saved before and restored after, untimed). The first ``warmup`` reasoning steps are not recorded;
    it stops after ``max_updates`` recorded ones. Memory is sampled after construction and after every
    update."""
    t0 = time.perf_counter()
    est = SceneEstimator(scene, cfg, rng)
    st = StreamTiming(startup_s=time.perf_counter() - t0)
    with est:
        pool = est.pool
        pids = [os.getpid()] + pool.worker_pids()
        sizes = pool.shard_sizes
        st.peak_memory_mb = _rss_mb(pids)
        t_tick, reasoning = None, 0
        for frame in frames:
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
                # right after the update, so that load on the machine affects both alike: the same
                # worlds, the same number of steps, nothing else; then the worlds are put back
                pool.save()
                t0 = time.perf_counter()
                pool.bare_step(n_steps)
                dt_bare = time.perf_counter() - t0
                bare_worker_s = list(pool.last_worker_seconds)
                pool.restore()
                if reasoning > warmup:
                    st.update_s.append(dt)
                    st.bare_s.append(dt_bare)
                    st.steps.append(n_steps)
                    st.main_s.append(dt - run_s)
                    st.exchange_s.append(run_s - max(worker_s))
                    st.shard_s.append(max(worker_s))
                    st.over_s.append(float(np.mean([(w - b) / n for w, b, n
                                                    in zip(worker_s, bare_worker_s, sizes)])))
            st.peak_memory_mb = max(st.peak_memory_mb, _rss_mb(pids))
            if max_updates is not None and len(st.update_s) >= max_updates:
                break
    if not st.update_s:
        raise ValueError("no reasoning step to time: the stream is shorter than two reasoning horizons")
    return st


def timing_row(st: StreamTiming) -> dict:
    """The figures of one measurement (times in ms unless named ``_s``)."""
    med, bare_med = float(np.median(st.update_s)), float(np.median(st.bare_s))
    return {"updates": len(st.update_s), "steps_per_update": int(np.median(st.steps)),
            "update_ms_median": 1e3 * med, "update_ms_p95": 1e3 * float(np.percentile(st.update_s, 95)),
            "bare_step_ms_median": 1e3 * bare_med, "ratio": med / bare_med, "updates_per_s": 1.0 / med,
            "startup_s": st.startup_s, "peak_memory_mb": st.peak_memory_mb,
            "main_ms_median": 1e3 * float(np.median(st.main_s)),
            "exchange_ms_median": 1e3 * float(np.median(st.exchange_s)),
            "slowest_shard_ms_median": 1e3 * float(np.median(st.shard_s)),
            "worker_overhead_us_per_particle": 1e6 * float(np.median(st.over_s))}


def bench_config(k: int, workers: int, config: EstimatorConfig | None = None) -> EstimatorConfig:
    """``config`` (default: the particle filter's defaults) with ``k`` particles and ``workers``."""
    return dataclasses.replace(config or EstimatorConfig(noise=NoiseConfig()), particles=k, workers=workers)


def bench_one(k: int, n_objects: int, workers: int, updates: int = 20, warmup: int = 3,
              seed: int = 0, config: EstimatorConfig | None = None) -> dict:
    """Figures for one (K, N) configuration; ``config`` replaces the particle filter's defaults
    (its particle count and workers are set to ``k`` and ``workers``)."""
    scene = bench_scene(n_objects)
    cfg = bench_config(k, workers, config)
    rng = np.random.default_rng(seed)
    frames = bench_frames(scene, warmup + updates, cfg.reasoner.horizon, rng)
    st = time_stream(scene, cfg, frames, rng, warmup=warmup)
    return {"particles": k, "objects": n_objects, "workers": workers, **timing_row(st)}


# -- the command ---------------------------------------------------------------------------------------
# (key, table heading, format) of the table's columns
SYNTHETIC_COLUMNS = [("particles", "K", "{}"), ("objects", "objects", "{}")]
TIMING_COLUMNS = [("update_ms_median", "median (ms)", "{:.1f}"), ("update_ms_p95", "p95 (ms)", "{:.1f}"),
                  ("bare_step_ms_median", "bare stepping (ms)", "{:.1f}"), ("ratio", "ratio", "{:.2f}")]
RESOURCE_COLUMNS = [("startup_s", "startup (s)", "{:.2f}"), ("peak_memory_mb", "peak memory (MB)", "{:.0f}")]
BREAKDOWN_COLUMNS = [("main_ms_median", "main process (ms)", "{:.2f}"),
                     ("slowest_shard_ms_median", "slowest shard (ms)", "{:.1f}"),
                     ("exchange_ms_median", "exchange (ms)", "{:.2f}"),
                     ("worker_overhead_us_per_particle", "worker over bare (us/particle)", "{:.0f}")]


def report(args, columns: list[tuple[str, str, str]], rows: Iterable[dict], meta: dict) -> int:
    """Print ``rows`` as they come as a Markdown table (``--breakdown``: with its columns), or, with
    ``--json``, all of them at the end as one JSON object ``{**meta, "results": rows}``."""
    if args.breakdown:
        columns = columns + BREAKDOWN_COLUMNS
    if not args.json:
        print("| " + " | ".join(c[1] for c in columns) + " |")
        print("|" + "---|" * len(columns), flush=True)
    done = []
    for r in rows:
        done.append(r)
        if not args.json:
            print("| " + " | ".join(fmt.format(r[key]) for key, _, fmt in columns) + " |", flush=True)
    if args.json:
        print(json.dumps({**meta, "results": done}))
    return 0


def particle_configs(args) -> list[tuple[int, EstimatorConfig]]:
    """``(K, configuration)`` for each ``--particles``: the ``--config`` file's or the particle filter's
    defaults, with K particles and ``--workers`` workers."""
    file_data = read_config_file(args.config) if args.config else None
    out = []
    for k in args.particles:
        cfg = None
        if file_data is not None:
            cfg = config_from_dict(file_data[0], path=args.config, lines=file_data[1], particles=k,
                                   base="particles")
        out.append((k, bench_config(k, args.workers, cfg)))
    return out


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--particles", type=int, nargs="+", default=[16, 64, 256])
    what = p.add_mutually_exclusive_group()
    what.add_argument("--objects", type=int, nargs="+", default=None,
                      help="synthetic scenes: resting boxes on a table (default 4 8 12)")
    what.add_argument("--scenario", metavar="NAME", action="append", default=None,
                      help="replay a built-in simulated scenario's observation stream (seed 0) instead; "
                           "repeat for several, 'all' for every built-in one (see `simulate --list`)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="worker processes (default: one per core)")
    p.add_argument("--updates", type=int, default=None,
                   help="timed updates per configuration (default 20; with --scenario, default: the whole "
                        "stream; given: the stream stops after this many)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument("--bag", action="store_true",
                   help="with --scenario: time a run of the stream read from JSON Lines against one read from "
                        "a ROS 2 bag of the same detections from two sources (/tf and PoseStamped)")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="estimator configuration file (see `scene-estimator config`) to time instead of the "
                        "particle filter's defaults, e.g. 'noise: {rolling_friction_range: [0.001, 0.01]}'")
    p.add_argument("--breakdown", action="store_true",
                   help="also print where an update's time goes: the main process's own work, the slowest "
                        "shard in its worker, the exchange (waiting for it, messages, shared arrays), and "
                        "each worker's time over bare stepping per particle")
    p.add_argument("--rerun-overhead", action="store_true",
                   help="measure the cost of --rerun recording instead (e.g. --particles 64)")


def run_bench(args) -> int:
    if args.updates is not None and args.updates < 1:
        raise ValueError(f"--updates must be >= 1, got {args.updates}")
    if args.bag and not args.scenario:
        raise ValueError("--bag compares the streams of scenarios: give --scenario NAME")
    if args.bag and args.breakdown:
        raise ValueError("--breakdown splits an update's time; --bag times whole runs: give one of them")
    if args.scenario:
        if args.rerun_overhead:
            raise ValueError("--rerun-overhead times the synthetic scenes (--objects), not --scenario")
        from .bench_scenario import run_scenario_bench
        return run_scenario_bench(args)
    objects = args.objects or [4, 8, 12]
    updates = args.updates or 20
    if args.rerun_overhead:
        from .recording import logging_overhead
        rows = [logging_overhead(k, n, args.workers, updates) for k in args.particles for n in objects]
        if args.json:
            print(json.dumps({"workers": args.workers, "results": rows}))
        else:
            for r in rows:
                print(f"K={r['particles']:>4} N={r['objects']:>3} update {r['update_ms_median']:.1f} ms  "
                      f"log {r['log_ms_median']:.2f} ms  overhead {100 * r['overhead']:.1f} %")
        return 0
    configs = particle_configs(args)

    def rows():
        for k, cfg in configs:
            for n in objects:
                print(f"bench: K={k}, {n} objects", file=sys.stderr, flush=True)
                yield bench_one(k, n, args.workers, updates, config=cfg)

    columns = (SYNTHETIC_COLUMNS + TIMING_COLUMNS + [("updates_per_s", "updates/s", "{:.1f}")]
               + RESOURCE_COLUMNS)
    meta = {"mode": "synthetic", "workers": args.workers, "cpu_count": os.cpu_count(), "config": args.config}
    return report(args, columns, rows(), meta)
