"""``scene-estimator bench``: update time of the estimator against bare pybullet stepping.

For each particle count K and number of dynamic objects N (5 cm boxes resting on a table, perceived
floating 1 cm with 3 mm noise), it times estimator updates of one reasoning horizon (0.08 s, 19
steps) and, after each update, in the same worker processes, bare ``stepSimulation`` of the same
worlds for the same number of steps (their states are saved before and restored after, untimed).
It reports the median and 95th percentile update time, the bare time, their ratio, updates per
second and the peak memory of the process and its workers; with
``--breakdown``, where the update's time goes (medians over the timed updates): the main process's
own work, the slowest shard in its worker, the exchange (the rest of the pool call: waiting for the
slowest shard, messages, shared arrays), and each worker's time over its bare stepping per particle.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

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


def bench_one(k: int, n_objects: int, workers: int, updates: int = 20, warmup: int = 3,
              seed: int = 0, config: EstimatorConfig | None = None) -> dict:
    """Figures for one (K, N) configuration; ``config`` replaces the particle filter's defaults
    (its particle count and workers are set to ``k`` and ``workers``)."""
    scene = bench_scene(n_objects)
    cfg = dataclasses.replace(config or EstimatorConfig(noise=NoiseConfig()), particles=k, workers=workers)
    horizon = cfg.reasoner.horizon
    n_steps = int(round(horizon / cfg.physics.time_step))
    rng = np.random.default_rng(seed)
    times, bare, main, exchange, shard, over = [], [], [], [], [], []
    peak = 0.0
    with SceneEstimator(scene, cfg, rng) as est:
        pool = est.pool
        pids = [os.getpid()] + pool.worker_pids()
        sizes = pool.shard_sizes
        for i, frame in enumerate(bench_frames(scene, warmup + updates, horizon, rng)):
            t0 = time.perf_counter()
            est.update(frame)
            dt = time.perf_counter() - t0
            run_s, worker_s = pool.last_run_seconds, list(pool.last_worker_seconds)
            # right after each update, so that load on the machine affects both alike: the same
            # worlds, the same number of steps, nothing else; then the worlds are put back
            pool.save()
            t0 = time.perf_counter()
            pool.bare_step(n_steps)
            dt_bare = time.perf_counter() - t0
            bare_s = list(pool.last_worker_seconds)
            pool.restore()
            if i >= warmup:
                times.append(dt)
                bare.append(dt_bare)
                main.append(dt - run_s)
                exchange.append(run_s - max(worker_s))
                shard.append(max(worker_s))
                over.append(np.mean([(w - b) / n for w, b, n in zip(worker_s, bare_s, sizes)]))
            peak = max(peak, _rss_mb(pids))
    med, p95, bare_med = float(np.median(times)), float(np.percentile(times, 95)), float(np.median(bare))
    return {"particles": k, "objects": n_objects, "workers": workers, "steps_per_update": n_steps,
            "update_ms_median": 1e3 * med, "update_ms_p95": 1e3 * p95, "bare_step_ms_median": 1e3 * bare_med,
            "ratio": med / bare_med, "updates_per_s": 1.0 / med, "peak_memory_mb": peak,
            "main_ms_median": 1e3 * float(np.median(main)),
            "exchange_ms_median": 1e3 * float(np.median(exchange)),
            "slowest_shard_ms_median": 1e3 * float(np.median(shard)),
            "worker_overhead_us_per_particle": 1e6 * float(np.median(over))}


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--particles", type=int, nargs="+", default=[16, 64, 256])
    p.add_argument("--objects", type=int, nargs="+", default=[4, 8, 12])
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="worker processes (default: one per core)")
    p.add_argument("--updates", type=int, default=20, help="timed updates per configuration")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
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
    if args.rerun_overhead:
        from .recording import logging_overhead
        rows = [logging_overhead(k, n, args.workers, args.updates) for k in args.particles for n in args.objects]
        if args.json:
            print(json.dumps({"workers": args.workers, "results": rows}))
        else:
            for r in rows:
                print(f"K={r['particles']:>4} N={r['objects']:>3} update {r['update_ms_median']:.1f} ms  "
                      f"log {r['log_ms_median']:.2f} ms  overhead {100 * r['overhead']:.1f} %")
        return 0
    rows = []
    extra = args.breakdown and not args.json
    if not args.json:
        print(f"{'K':>5} {'N':>3} {'median ms':>10} {'p95 ms':>8} {'bare ms':>8} {'ratio':>6} "
              f"{'upd/s':>7} {'peak MB':>8}"
              + (f" {'main ms':>8} {'shard ms':>9} {'exch. ms':>9} {'over us/particle':>17}" if extra else ""))
    file_data = read_config_file(args.config) if args.config else None
    for k in args.particles:
        cfg = None
        if file_data is not None:
            cfg = config_from_dict(file_data[0], path=args.config, lines=file_data[1], particles=k,
                                   base="particles")
        for n in args.objects:
            r = bench_one(k, n, args.workers, args.updates, config=cfg)
            rows.append(r)
            if not args.json:
                print(f"{k:>5} {n:>3} {r['update_ms_median']:>10.1f} {r['update_ms_p95']:>8.1f} "
                      f"{r['bare_step_ms_median']:>8.1f} {r['ratio']:>6.2f} {r['updates_per_s']:>7.1f} "
                      f"{r['peak_memory_mb']:>8.0f}"
                      + (f" {r['main_ms_median']:>8.2f} {r['slowest_shard_ms_median']:>9.1f} "
                         f"{r['exchange_ms_median']:>9.2f} {r['worker_overhead_us_per_particle']:>17.0f}"
                         if extra else ""), flush=True)
    if args.json:
        print(json.dumps({"workers": args.workers, "cpu_count": os.cpu_count(), "results": rows}))
    return 0
