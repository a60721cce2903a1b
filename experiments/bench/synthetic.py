"""The synthetic benchmark scene (``bench --objects``): N 5 cm boxes resting on a table, perceived
floating 1 cm with 3 mm noise, one frame per reasoning horizon."""
from __future__ import annotations

import numpy as np

from estimator.config import EstimatorConfig
from estimator.observations import Detection, Frame
from experiments.bench.timing import bench_config, time_stream, timing_row
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
    """``n`` frames, ``horizon`` seconds apart, each detecting every box 1 cm above its resting place
    with 3 mm of Gaussian noise (per axis)."""
    rest = {o.id: np.array(o.position) + [0, 0, 0.01] for o in scene.objects if not o.static}
    for k in range(n):
        yield Frame(k * horizon, {oid: Detection(p + rng.normal(0, 0.003, 3), np.array([0, 0, 0, 1.0]))
                                  for oid, p in rest.items()})


def bench_one(k: int, n_objects: int, workers: int, updates: int = 20, warmup: int = 3,
              seed: int = 0, config: EstimatorConfig | None = None, resting: bool = False) -> dict:
    """Figures for one (K, N) configuration; ``config`` replaces the particle filter's defaults
    (its particle count and workers are set to ``k`` and ``workers``); ``resting``: measure the
    resting objects' share of bare stepping too (:func:`~experiments.bench.timing.time_stream`)."""
    scene = bench_scene(n_objects)
    cfg = bench_config(k, workers, config)
    rng = np.random.default_rng(seed)
    frames = bench_frames(scene, warmup + updates, cfg.reasoner.horizon, rng)
    st = time_stream(scene, cfg, frames, rng, warmup=warmup, resting=resting)
    return {"particles": k, "objects": n_objects, "workers": workers, **timing_row(st)}
