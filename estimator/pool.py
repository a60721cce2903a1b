"""The particle worlds, one persistent pybullet world per particle slot, held in this process or
sharded over persistent worker processes that exchange only numpy arrays.

Slot ``k`` always lives in the same world, whatever the number of workers, and a world's history
depends only on the arrays it is given, so results do not depend on ``workers`` (see DESIGN.md:
contact caches survive pose resets, so a world must not be shared between particle slots).
"""
from __future__ import annotations

import multiprocessing as mp
import traceback
from dataclasses import dataclass

import numpy as np

from physics.scene import Scene
from physics.visibility import Camera, local_sample_points, visible_fraction
from physics.world import PhysicsSettings, World

from .propagate import ParticleWorld, StepInput, propagate


@dataclass
class BatchInput:
    """Inputs for K particles (see :class:`~estimator.propagate.StepInput` for the per-particle
    shapes; every array here has a leading K axis, except ``vis_query (M,)``: objects whose
    visibility to the camera is wanted after the update)."""

    poses: np.ndarray
    velocities: np.ndarray
    params: np.ndarray
    modes: np.ndarray
    check: np.ndarray
    target: np.ndarray
    target_vel: np.ndarray
    contents: np.ndarray
    depenetrate: np.ndarray
    reset: np.ndarray
    vis_query: np.ndarray

    def shard(self, lo: int, hi: int) -> "BatchInput":
        return BatchInput(*(getattr(self, f)[lo:hi] for f in _PER_PARTICLE), self.vis_query)


_PER_PARTICLE = ("poses", "velocities", "params", "modes", "check", "target", "target_vel", "contents",
                 "depenetrate", "reset")


@dataclass
class BatchOutput:
    """Outputs for K particles: poses (K, M, 7), velocities (K, M, 6), modes (K, M), max_divergence
    (K, M), aabbs (K, M, 2, 3), finite (K,), visible (K, M) (fraction seen; 0 where not queried)."""

    poses: np.ndarray
    velocities: np.ndarray
    modes: np.ndarray
    max_divergence: np.ndarray
    aabbs: np.ndarray
    finite: np.ndarray
    visible: np.ndarray


class _Shard:
    """The worlds of slots ``[lo, hi)``; runs in a worker process or in the caller's."""

    def __init__(self, scene: Scene, settings: PhysicsSettings, lo: int, hi: int):
        self.worlds = [ParticleWorld(World(scene, settings)) for _ in range(lo, hi)]
        self.camera = Camera(scene.camera) if scene.camera is not None else None
        self.points = None
        if self.camera is not None:
            w = self.worlds[0].world
            self.points = {int(i): local_sample_points(w, int(i)) for i in range(w.num_objects)}

    def initial_params(self) -> np.ndarray:
        w = self.worlds[0].world
        out = np.zeros((w.num_objects, 5))
        for i in range(w.num_objects):
            d = w.get_dynamics(i)
            out[i] = [d["lateral_friction"], d["rolling_friction"], d["spinning_friction"],
                      d["restitution"], d["mass"]]
        return out

    def run(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False) -> BatchOutput:
        outs, vis = [], []
        q = np.flatnonzero(batch.vis_query)
        for k, pw in enumerate(self.worlds):
            inp = StepInput(*(getattr(batch, f)[k] for f in _PER_PARTICLE))
            out = propagate(pw, inp, n_steps, d_sim_perc, lazy)
            outs.append(out)
            v = np.zeros(len(out.modes))
            if self.camera is not None and len(q) and out.finite:
                v[q] = visible_fraction(pw.world, self.camera, q, self.points, out.poses[q])
            vis.append(v)
        return BatchOutput(np.stack([o.poses for o in outs]), np.stack([o.velocities for o in outs]),
                           np.stack([o.modes for o in outs]), np.stack([o.max_divergence for o in outs]),
                           np.stack([o.aabbs for o in outs]), np.array([o.finite for o in outs]),
                           np.stack(vis))

    def bare_step(self, n_steps: int) -> None:
        """Step every world ``n_steps`` times and nothing else (the benchmark's reference)."""
        for pw in self.worlds:
            pw.world.step(n_steps)

    def close(self) -> None:
        for pw in self.worlds:
            pw.world.close()


def _worker_main(conn, scene, settings, lo, hi):
    shard = None
    try:
        shard = _Shard(scene, settings, lo, hi)
        conn.send(("ok", shard.initial_params()))
        while True:
            msg = conn.recv()
            if msg[0] == "close":
                break
            if msg[0] == "bare":
                shard.bare_step(msg[1])
                conn.send(("ok", None))
                continue
            _, batch, n_steps, d, lazy = msg
            try:
                conn.send(("ok", shard.run(batch, n_steps, d, lazy)))
            except Exception:  # report, keep serving
                conn.send(("error", traceback.format_exc()))
    except (EOFError, KeyboardInterrupt):
        pass
    except Exception:
        try:
            conn.send(("error", traceback.format_exc()))
        except Exception:
            pass
    finally:
        if shard is not None:
            shard.close()
        conn.close()


def shard_bounds(n_particles: int, n_shards: int) -> list[tuple[int, int]]:
    """Contiguous, nearly equal slot ranges ``[(lo, hi), ...]`` for ``n_shards`` shards."""
    n_shards = max(1, min(n_shards, n_particles))
    edges = np.linspace(0, n_particles, n_shards + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


class WorldPool:
    """K particle worlds. ``workers=0`` keeps them in this process; otherwise that many worker
    processes each own a contiguous shard of slots. Use as a context manager or call :meth:`close`."""

    def __init__(self, scene: Scene, n_particles: int, workers: int = 0,
                 settings: PhysicsSettings | None = None):
        self.n_particles = n_particles
        self.workers = workers
        settings = settings or PhysicsSettings()
        self._local: _Shard | None = None
        self._procs, self._conns, self._bounds = [], [], []
        if workers <= 0:
            self._local = _Shard(scene, settings, 0, n_particles)
            self.initial_params = self._local.initial_params()
            return
        ctx = mp.get_context("spawn")
        self._bounds = shard_bounds(n_particles, workers)
        try:
            for lo, hi in self._bounds:
                parent, child = ctx.Pipe()
                p = ctx.Process(target=_worker_main, args=(child, scene, settings, lo, hi), daemon=True)
                p.start()
                child.close()
                self._procs.append(p)
                self._conns.append(parent)
            params = [self._receive(c) for c in self._conns]
        except BaseException:
            self.close()
            raise
        self.initial_params = params[0]

    @staticmethod
    def _receive(conn):
        status, payload = conn.recv()
        if status != "ok":
            raise RuntimeError(f"particle worker failed:\n{payload}")
        return payload

    def run(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False) -> BatchOutput:
        """Propagate all K particles by ``n_steps`` steps (see :func:`~estimator.propagate.propagate`)."""
        if self._local is not None:
            return self._local.run(batch, n_steps, d_sim_perc, lazy)
        for conn, (lo, hi) in zip(self._conns, self._bounds):
            conn.send(("run", batch.shard(lo, hi), n_steps, d_sim_perc, lazy))
        parts = [self._receive(conn) for conn in self._conns]
        return BatchOutput(*(np.concatenate([getattr(p, f) for p in parts])
                             for f in ("poses", "velocities", "modes", "max_divergence", "aabbs",
                                       "finite", "visible")))

    def bare_step(self, n_steps: int) -> None:
        """Step every world ``n_steps`` times, with the same sharding and nothing else."""
        if self._local is not None:
            self._local.bare_step(n_steps)
            return
        for conn in self._conns:
            conn.send(("bare", n_steps))
        for conn in self._conns:
            self._receive(conn)

    def worker_pids(self) -> list[int]:
        return [p.pid for p in self._procs]

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            self._local = None
        for conn in self._conns:
            try:
                conn.send(("close",))
            except (OSError, BrokenPipeError):
                pass
        for p in self._procs:
            p.join(timeout=5)
            if p.is_alive():
                p.terminate()
        for conn in self._conns:
            conn.close()
        self._procs, self._conns = [], []

    def __enter__(self) -> "WorldPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
