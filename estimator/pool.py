"""The particle worlds: one persistent copy of the scene per particle slot, the copies packed side by
side into a few pybullet clients (:class:`~physics.group.WorldGroup`), held in this process or
sharded over persistent worker processes. Workers and caller share the particles' input and output
arrays in one block of shared memory; the pipes carry only commands.

Memory and start-up follow the number of clients, not K: a client costs about 28 MB, a copy of a
tabletop scene a fraction of a megabyte. The slots are split into ``worlds`` contiguous groups, one
client each, by :func:`shard_bounds` of K alone; a worker holds whole groups. Slot ``k`` therefore
always lives in the same copy of the same client, whatever the number of workers, and a copy's
history depends only on the arrays it is given, so results do not depend on ``workers`` (see
DESIGN.md: contact caches survive pose resets, so a copy must not be shared between particle
slots).
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import time
import traceback
from collections import OrderedDict

import numpy as np

from physics.group import WorldGroup
from physics.scene import CameraSpec, Scene
from physics.transforms import quat_rotate
from physics.sightlines import Solids
from physics.visibility import (Camera, first_copies, local_box, local_sample_points, rays_clear_of, seen_points,
                                solid_box, visible_enough, visible_fractions)
from physics.world import PhysicsSettings, World

from .propagate import BatchInput, BatchOutput, ParticleWorld, propagate_batch
from .shared_batch import SharedBatch

__all__ = ["BatchInput", "BatchOutput", "WorldPool", "shard_bounds"]

log = logging.getLogger(__name__)


class _Shard:
    """The particle slots of consecutive groups ``[(lo, hi), ...]`` (one client each); runs in a
    worker process or in the caller's."""

    def __init__(self, scene: Scene, settings: PhysicsSettings, groups: list[tuple[int, int]]):
        self.groups: list[WorldGroup] = []
        try:
            for lo, hi in groups:
                self.groups.append(WorldGroup(scene, settings, hi - lo))
        except BaseException:
            self.close()
            raise
        self.worlds = [ParticleWorld(w) for g in self.groups for w in g.worlds]
        self._group_of = [j for j, g in enumerate(self.groups) for _ in g.worlds]  # slot -> its client
        self.scene_boxes = self.worlds[0].world.aabbs()  # (M, 2, 3): as built, at the scene's poses
        self._saved: list[int] = []
        # per camera: world -> (poses, fractions) of its last ray tests (the most recent cameras)
        self._vis_caches: OrderedDict[tuple, dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]] = OrderedDict()
        self._cameras: dict[tuple, Camera] = {}
        self.scene, self.settings = scene, settings
        self.camera = Camera(scene.camera) if scene.camera is not None else None
        self.points = None
        if self.camera is not None:
            self._sample_points(self.worlds[0].world)

    def _sample_points(self, w: World) -> None:
        """Sample points, box centres and radii of every object, read from world ``w``."""
        self.points = {int(i): local_sample_points(w, int(i), VISIBILITY_POINTS_PER_AXIS)
                       for i in range(w.num_objects)}
        boxes = [local_box(w, i) for i in range(w.num_objects)]
        self.box_centres = np.array([c for c, _ in boxes])  # (M, 3), object frame
        self.radii = np.array([np.linalg.norm(h) for _, h in boxes])  # (M,) m
        self.solids = {i: b for i in range(w.num_objects) if (b := solid_box(w, i, boxes[i])) is not None}

    def camera_for(self, spec: CameraSpec) -> Camera:
        """The :class:`Camera` of ``spec`` (built once). The first camera of a scene without one reads
        the objects' sample points in a scratch world, leaving the particle worlds untouched."""
        if self.points is None:
            scratch = World(self.scene, self.settings)
            try:
                self._sample_points(scratch)
            finally:
                scratch.close()
        key = camera_key(spec)
        cam = self._cameras.pop(key, None)
        if cam is None:
            cam = self.camera if self.camera is not None and key == camera_key(self.camera.spec) else Camera(spec)
        self._cameras[key] = cam  # the most recent last; the oldest go (a search samples new viewpoints)
        while len(self._cameras) > CACHED_CAMERAS:
            del self._cameras[next(iter(self._cameras))]
        return cam

    def initial_params(self) -> np.ndarray:
        w = self.worlds[0].world
        out = np.zeros((w.num_objects, 5))
        for i in range(w.num_objects):
            d = w.get_dynamics(i)
            out[i] = [d["lateral_friction"], d["rolling_friction"], d["spinning_friction"],
                      d["restitution"], d["mass"]]
        return out

    def run(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False,
            moving: bool = False, cameras: tuple[CameraSpec, ...] | None = None) -> BatchOutput:
        out = propagate_batch(self.worlds, batch, n_steps, d_sim_perc, lazy, moving)
        q = np.flatnonzero(batch.vis_query) if batch.vis_query is not None else np.zeros(0, int)
        if cameras is None:
            cams = [self.camera] if self.camera is not None else []
        else:
            cams = [self.camera_for(c) for c in cameras]
        if cams and len(q):  # several cameras: an object is as visible as the best of them shows it
            out.visible[:, q] = np.max([self._visibility(c, out.poses, out.finite, q) for c in cams], axis=0)
        return out

    def look(self, poses: np.ndarray, place: np.ndarray, targets: np.ndarray, cameras: tuple[CameraSpec, ...],
             threshold: float | None = None, only: np.ndarray | None = None) -> np.ndarray:
        """Visible fractions ``(V, K, n)`` of objects ``targets (n,)`` to each of the V ``cameras`` in
        each of this shard's K worlds with the objects ``place`` set at ``poses (K, M, 7)`` (the
        others stay as the world holds them: parked when unknown); with ``threshold``, bool: whether
        the fraction reaches it (:func:`~physics.visibility.visible_enough`, fewer rays). ``only
        (K,)`` bool: the worlds to look in (the others answer 0). A world that holds other poses is
        set to them, its client saved and restored, so that the filter's next update is unchanged."""
        cams = [self.camera_for(c) for c in cameras]
        place = [int(i) for i in place]
        targets = [int(i) for i in targets]
        slots = np.flatnonzero(np.ones(len(self.worlds), bool) if only is None else only).tolist()
        out = np.zeros((len(cams), len(self.worlds), len(targets)), bool if threshold is not None else float)
        if not slots:
            return out
        worlds = [self.worlds[k].world for k in slots]
        now = [w.get_poses() for w in worlds]
        moved = [j for j, k in enumerate(slots) if place and not np.array_equal(now[j][place], poses[k, place])]
        ids = {g: self.groups[g].save_state() for g in sorted({self._group_of[slots[j]] for j in moved})}
        try:
            for j in moved:
                worlds[j].set_poses(poses[slots[j], place], place)
                now[j] = worlds[j].get_poses()
            boxes = np.stack([w.aabbs() for w in worlds])  # (K, M, 2, 3): what may hide the targets
            convex = np.array([self.scene.objects[i].shape in CONVEX_SHAPES for i in targets])
            bodies = dict(boxes=boxes, convex=convex, solids=Solids.posed(self.solids, np.stack(now)))
            tp = poses[slots][:, targets]
            if threshold is not None:
                out[:, slots] = visible_enough(worlds, cams, targets, self.points, tp, threshold, **bodies)
            else:
                seen, counts = seen_points(worlds, cams, targets, self.points, tp, **bodies)
                out[:, slots] = seen / np.maximum(counts, 1)
            return out
        finally:
            for j, sid in ids.items():
                self.groups[j].restore_state(sid)
                self.groups[j].remove_state(sid)

    def _visibility(self, camera: Camera, poses: np.ndarray, finite: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Visible fractions ``(K, len(q))`` of objects ``q`` in the worlds at ``poses (K, M, 7)``
        (zero for exploded worlds). An object keeps the answer of its world's last ray tests when it
        has not moved (bit for bit) and nothing that moved since came near its rays
        (:func:`~physics.visibility.rays_clear_of`): most of a resting scene casts no ray."""
        key = camera_key(camera.spec)
        cache = self._vis_caches.pop(key, {})
        self._vis_caches[key] = cache  # the most recent last
        while len(self._vis_caches) > VISIBILITY_CACHED_CAMERAS:
            self._vis_caches.popitem(last=False)
        K, n = len(self.worlds), len(q)
        vis = np.zeros((K, n))
        need = np.zeros((K, n), dtype=bool)
        now = poses[..., :3] + quat_rotate(poses[..., 3:], self.box_centres[None])  # (K, M, 3), at once
        for k in np.flatnonzero(finite).tolist():
            need[k] = True
            cached = cache.get(k)
            if cached is None:
                continue
            old, row, old_centres = cached
            moved = np.any(poses[k] != old, axis=-1)
            keep = ~np.isnan(row[q]) & ~moved[q]
            if keep.any() and moved.any():
                m = np.flatnonzero(moved)
                centres = now[k, q]
                for c in (old_centres, now[k]):
                    keep &= rays_clear_of(camera, centres, self.radii[q], c[m], self.radii[m])
            vis[k, keep] = row[q][keep]
            need[k] = ~keep
        todo = np.flatnonzero(need.any(axis=1)).tolist()
        if todo:
            fresh = visible_fractions([self.worlds[k].world for k in todo], camera, q, self.points,
                                      poses[np.ix_(todo, q)], need[todo])
            vis[todo] = np.where(need[todo], fresh, vis[todo])
        for k in np.flatnonzero(finite).tolist():
            row = np.full(poses.shape[1], np.nan)
            row[q] = vis[k]
            cache[k] = (poses[k].copy(), row, now[k])
        return vis

    def bare_step(self, n_steps: int) -> None:
        """Step every client ``n_steps`` times and nothing else (the benchmark's reference)."""
        for g in self.groups:
            g.step(n_steps)

    def save(self) -> None:
        """Save every client's state in memory (replacing any state saved before)."""
        self.drop_saved()
        self._saved = [g.save_state() for g in self.groups]

    def restore(self) -> None:
        """Return every client to the state of the last :meth:`save`, and forget it."""
        for g, sid in zip(self.groups, self._saved):
            g.restore_state(sid)
        self.drop_saved()

    def drop_saved(self) -> None:
        for g, sid in zip(self.groups, self._saved):
            g.remove_state(sid)
        self._saved = []

    def close(self) -> None:
        for g in self.groups:
            g.close()


def _worker_main(conn, scene, settings, groups, buffer, n_particles):
    shard = None
    lo, hi = groups[0][0], groups[-1][1]
    try:
        shard = _Shard(scene, settings, groups)
        shared = SharedBatch(buffer, n_particles, len(scene.objects))
        conn.send(("ok", (shard.initial_params(), shard.scene_boxes)))
        while True:
            msg = conn.recv()
            if msg[0] == "close":
                break
            t0 = time.perf_counter()
            if msg[0] == "look":
                try:
                    conn.send(("ok", shard.look(*msg[1:])))
                except Exception:
                    conn.send(("error", traceback.format_exc()))
                continue
            if msg[0] in ("bare", "save", "restore"):
                if msg[0] == "bare":
                    shard.bare_step(msg[1])
                else:
                    getattr(shard, msg[0])()
                conn.send(("ok", time.perf_counter() - t0))
                continue
            _, n_steps, d, lazy, moving, cameras = msg
            try:
                shared.write_outputs(lo, hi, shard.run(shared.inputs(lo, hi), n_steps, d, lazy, moving, cameras))
                conn.send(("ok", time.perf_counter() - t0))  # the reply carries the worker's time
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


VISIBILITY_POINTS_PER_AXIS = 2
"""Sample points of an object for the particles' visibility test: its centre and 8 points towards
the corners of its box (:func:`~physics.visibility.local_sample_points`; 3 would give 27, three
times the ray tests, for a fraction that only decides whether it passes the visibility threshold)."""

CONVEX_SHAPES = ("sphere", "box", "cylinder")
"""Shapes whose visibility sample points lie inside a convex body: a ray to one that no other body's
box is on reaches it (:func:`~physics.visibility.visible_fractions` skips its ray test)."""

VISIBILITY_CACHED_CAMERAS = 4
"""Cameras whose last ray tests each shard keeps (the scene's and a few moving ones): a cached
answer is exact, so a camera pushed out only costs its next ray tests again."""

CACHED_CAMERAS = 256
"""Cameras a shard keeps built (the most recently used): a search plans from new sampled viewpoints
every time, which must not grow the worker's memory without bound."""


def camera_key(spec: CameraSpec) -> tuple:
    """A hashable key of a camera's numbers (positions may be tuples, lists or arrays)."""
    return tuple(float(x) for v in (spec.position, spec.target, spec.up) for x in np.ravel(v)) + (
        float(spec.fov_deg), float(spec.aspect), float(spec.near), float(spec.far))


DEFAULT_WORLDS = 8
"""Default number of pybullet clients the particle slots are packed into."""


class WorldPool:
    """K particle worlds, packed into ``worlds`` pybullet clients (default ``min(K, 8)``; fixed by
    the caller, never by ``workers``, so that results do not depend on ``workers``). ``workers=0``
    keeps them in this process; otherwise ``min(workers, worlds)`` worker processes each own a
    contiguous run of clients. Use as a context manager or call :meth:`close`.

    After :meth:`run` (and :meth:`bare_step`), ``last_run_seconds`` is the wall time of the call in
    this process and ``last_worker_seconds`` the time each shard took in its worker (the benchmark's
    breakdown). A worker process that dies (killed, out of memory) is restarted by the next
    :meth:`run`, which reports its particles as not finite (the caller re-seeds them) and counts it
    in ``restarts``; an exception inside a live worker is a ``RuntimeError``. ``scene_boxes (M, 2,
    3)``: the objects' world AABBs (m) at the scene's poses, read when the worlds were built."""

    def __init__(self, scene: Scene, n_particles: int, workers: int = 0,
                 settings: PhysicsSettings | None = None, worlds: int | None = None):
        if n_particles < 1:
            raise ValueError(f"a world pool needs at least one particle, got {n_particles}")
        if worlds is not None and worlds < 1:
            raise ValueError(f"worlds must be >= 1, got {worlds}")
        self.n_particles = n_particles
        self.workers = workers
        settings = settings or PhysicsSettings()
        self.groups = shard_bounds(n_particles, min(n_particles, worlds or DEFAULT_WORLDS))
        self._local: _Shard | None = None
        self.last_run_seconds = 0.0
        self.last_worker_seconds: list[float] = []
        self._procs, self._conns, self._bounds = [], [], []
        self.restarts = 0
        if workers <= 0:
            self._local = _Shard(scene, settings, self.groups)
            self.initial_params, self.scene_boxes = self._local.initial_params(), self._local.scene_boxes
            return
        self._ctx = mp.get_context("spawn")
        self._runs = [self.groups[a:b] for a, b in shard_bounds(len(self.groups), workers)]
        self._bounds = [(run[0][0], run[-1][1]) for run in self._runs]
        self._buffer = self._ctx.RawArray("b", SharedBatch.nbytes(n_particles, len(scene.objects)))
        self._shared = SharedBatch(self._buffer, n_particles, len(scene.objects))
        self._scene, self._settings = scene, settings
        try:
            for j in range(len(self._runs)):
                self._start_worker(j)
            params = [self._receive(c) for c in self._conns]
        except BaseException:
            self.close()
            raise
        self.initial_params, self.scene_boxes = params[0]

    def _start_worker(self, j: int) -> None:
        """Start (or restart) the worker process of shard ``j``; it answers with the initial
        parameters once its worlds are built."""
        parent, child = self._ctx.Pipe()
        p = self._ctx.Process(target=_worker_main, daemon=True,
                              args=(child, self._scene, self._settings, self._runs[j], self._buffer,
                                    self.n_particles))
        p.start()
        child.close()
        if j < len(self._procs):
            self._conns[j].close()
            self._procs[j], self._conns[j] = p, parent
        else:
            self._procs.append(p)
            self._conns.append(parent)

    @staticmethod
    def _recv(conn) -> tuple[str, object]:
        try:
            return conn.recv()
        except (EOFError, OSError):
            return "dead", "the worker process died (killed, or out of memory?)"

    @classmethod
    def _receive(cls, conn):
        status, payload = cls._recv(conn)
        if status != "ok":
            raise RuntimeError(f"particle worker failed:\n{payload}")
        return payload

    def run(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False,
            moving: bool = False, cameras: tuple[CameraSpec, ...] | None = None) -> BatchOutput:
        """Propagate all K particles by ``n_steps`` steps (see :func:`~estimator.propagate.propagate`;
        ``moving``: divergence tests of objects teleported in motion carry their target on at its
        velocity); visibility of ``batch.vis_query`` to ``cameras`` (None: the scene's camera;
        several: the largest fraction any of them sees)."""
        t0 = time.perf_counter()
        if self._local is not None:
            out = self._local.run(batch, n_steps, d_sim_perc, lazy, moving, cameras)
            self.last_run_seconds = time.perf_counter() - t0
            self.last_worker_seconds = [self.last_run_seconds]
            return out
        self._shared.write_inputs(batch)
        for conn in self._conns:
            try:
                conn.send(("run", n_steps, d_sim_perc, lazy, moving, cameras))
            except OSError:
                pass  # a dead worker: its reply says so
        replies = [self._recv(conn) for conn in self._conns]  # all of them: no reply is left unread
        for status, payload in replies:
            if status == "error":  # an exception in a live worker is a bug: report it
                raise RuntimeError(f"particle worker failed:\n{payload}")
        out = self._shared.outputs()
        for j, (status, _) in enumerate(replies):
            if status == "dead":  # a worker that died: its particles are lost, the worker restarted
                lo, hi = self._bounds[j]
                log.warning("particle worker %d (slots %d-%d) died; restarting it, its particles are "
                            "re-seeded from the others", j, lo, hi - 1)
                out.finite[lo:hi] = False
                out.poses[lo:hi], out.velocities[lo:hi] = batch.poses[lo:hi], 0.0
                out.modes[lo:hi], out.visible[lo:hi], out.aabbs[lo:hi] = batch.modes[lo:hi], 0.0, np.nan
                self._start_worker(j)
                self._receive(self._conns[j])
                self.restarts += 1
        self.last_run_seconds = time.perf_counter() - t0
        self.last_worker_seconds = [payload if status == "ok" else 0.0 for status, payload in replies]
        return out

    def look(self, poses: np.ndarray, place: np.ndarray, targets: np.ndarray, cameras: tuple[CameraSpec, ...],
             threshold: float | None = None) -> np.ndarray:
        """Visible fractions ``(V, K, n)`` of objects ``targets (n,)`` to each of the V ``cameras``
        in every particle world, the objects ``place`` set at the particles' ``poses (K, M, 7)``
        (occlusion by everything each particle believes); with ``threshold``, bool: whether each
        reaches it. Particles equal in every pose share the answer of the first of them (each
        distinct one is looked at in its own world); the worlds are left as they were."""
        poses = np.asarray(poses, dtype=float)
        first = first_copies(poses)
        only = first == np.arange(len(poses))
        if self._local is not None:
            return self._local.look(poses, place, targets, tuple(cameras), threshold, only)[:, first]
        for conn, (lo, hi) in zip(self._conns, self._bounds):
            conn.send(("look", poses[lo:hi], place, targets, tuple(cameras), threshold, only[lo:hi]))
        return np.concatenate([self._receive(conn) for conn in self._conns], axis=1)[:, first]

    def bare_step(self, n_steps: int) -> None:
        """Step every world ``n_steps`` times, with the same sharding and nothing else."""
        t0 = time.perf_counter()
        if self._local is not None:
            self._local.bare_step(n_steps)
            self.last_worker_seconds = [time.perf_counter() - t0]
            return
        for conn in self._conns:
            conn.send(("bare", n_steps))
        self.last_worker_seconds = [self._receive(conn) for conn in self._conns]

    def save(self) -> None:
        """Save the state of every particle world (to be put back by :meth:`restore`; the benchmark
        steps the worlds between the two)."""
        self._command("save")

    def restore(self) -> None:
        """Put every particle world back in the state of the last :meth:`save`."""
        self._command("restore")

    def _command(self, name: str) -> None:
        if self._local is not None:
            getattr(self._local, name)()
            return
        for conn in self._conns:
            conn.send((name,))
        for conn in self._conns:
            self._receive(conn)

    @property
    def shard_sizes(self) -> list[int]:
        """Number of particle worlds in each worker (one entry, K, in this process)."""
        return [hi - lo for lo, hi in self._bounds] or [self.n_particles]

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
