"""``bench --rerun-overhead``: what recording (:class:`experiments.recording.Recorder`) costs an update."""
from __future__ import annotations

import os
import tempfile
import time

import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.filter import SceneEstimator
from experiments.bench.synthetic import bench_frames, bench_scene
from experiments.recording import Recorder


def logging_overhead(k: int = 64, n_objects: int = 8, workers: int = 0, updates: int = 20, warmup: int = 3,
                     seed: int = 0, path: str | os.PathLike | None = None) -> dict:
    """Cost of recording on the ``bench`` scene (K particles, ``n_objects`` boxes on a table, one
    frame per reasoning step): two estimators with the same seed and frames, updated alternately (so
    that load on the machine affects both alike), one bare, one followed by ``log_frame`` and
    ``log_belief`` of a :class:`Recorder`.

    Returns medians in ms over the ``updates`` timed updates: ``update_ms_median`` (bare),
    ``recorded_update_ms_median`` (update + logging), ``log_ms_median`` (the logging calls alone), and
    ``overhead`` = total logging time / total bare update time (buffer writes included), and
    ``cpu_overhead`` = extra CPU time of this process (all its threads, rerun's encoder and file
    writer included; worker processes excluded) per update / bare update wall time.
    ``path``: the ``.rrd`` to write (default: a temporary file, deleted).
    """

    scene = bench_scene(n_objects)
    cfg = EstimatorConfig(particles=k, workers=workers, noise=NoiseConfig())
    frames = list(bench_frames(scene, warmup + updates, cfg.reasoner.horizon, np.random.default_rng([seed, 1])))
    bare, upd, logt, cpu_bare, cpu_rec = [], [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        target = path if path is not None else os.path.join(tmp, "bench.rrd")
        with SceneEstimator(scene, cfg, np.random.default_rng(seed)) as est_a, \
                SceneEstimator(scene, cfg, np.random.default_rng(seed)) as est_b, Recorder(target, scene) as rec:
            for i, frame in enumerate(frames):
                c0, t0 = time.process_time(), time.perf_counter()
                est_a.update(frame)
                c1, t1 = time.process_time(), time.perf_counter()
                belief = est_b.update(frame)
                t2 = time.perf_counter()
                rec.log_frame(frame)
                if belief is not None:
                    rec.log_belief(belief)
                c3, t3 = time.process_time(), time.perf_counter()
                if i >= warmup:
                    bare.append(t1 - t0)
                    upd.append(t2 - t1)
                    logt.append(t3 - t2)
                    cpu_bare.append(c1 - c0)
                    cpu_rec.append(c3 - c1)
        size = os.path.getsize(target)
    return {"particles": k, "objects": n_objects, "workers": workers, "updates": updates,
            "update_ms_median": 1e3 * float(np.median(bare)),
            "recorded_update_ms_median": 1e3 * float(np.median(np.add(upd, logt))),
            "log_ms_median": 1e3 * float(np.median(logt)),
            "overhead": sum(logt) / sum(bare),
            "cpu_overhead": (sum(cpu_rec) - sum(cpu_bare)) / sum(bare),
            "rrd_bytes": size}
