"""A shard of the particle worlds: consecutive groups of particle slots, one pybullet client each
(:class:`~physics.group.WorldGroup`), stepped, queried and ray-tested together, in a worker process
(:func:`_worker_main`, serving the pool's commands) or in the caller's (:mod:`estimator.worlds.pool`)."""
from __future__ import annotations

import gc
import logging
import time
import traceback
from collections import OrderedDict

import numpy as np

from physics.group import WorldGroup
from physics.scene import CameraSpec, Scene
from physics.sightlines import Solids
from physics.sleep import asleep
from physics.transforms import quat_rotate
from physics.visibility import (
    Camera,
    local_box,
    local_sample_points,
    rays_clear_of,
    seen_points,
    solid_box,
    visible_enough,
    visible_fractions,
)
from physics.world import PhysicsSettings, World

from .batch import PER_PARTICLE, BatchInput, BatchOutput, ParticleWorld
from .propagate import propagate_batch
from .shared_batch import SharedBatch

log = logging.getLogger(__name__)


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


class _Shard:
    """The particle slots of consecutive groups ``[(lo, hi), ...]`` (one client each); runs in a
    worker process or in the caller's.

    ``active`` ``(n,)`` bool over the shard's ``n`` slots (default all): the slots in use. A client
    holds its copies up to its last slot in use (at least one), and builds more as later runs use
    more (:meth:`use`, :meth:`WorldGroup.grow`); a slot that falls out of use has its objects parked
    (asleep, no collisions: stepping its client costs next to nothing for it)."""

    def __init__(self, scene: Scene, settings: PhysicsSettings, groups: list[tuple[int, int]],
                 active: np.ndarray | None = None):
        n = groups[-1][1] - groups[0][0]
        active = np.ones(n, bool) if active is None else np.asarray(active, bool)
        self.groups: list[WorldGroup] = []
        self._first = [lo - groups[0][0] for lo, _ in groups]  # each group's first slot, shard-local
        self._group_of = [j for j, (lo, hi) in enumerate(groups) for _ in range(lo, hi)]  # slot -> its client
        self.worlds: list[ParticleWorld | None] = [None] * n
        self.boxes = None  # the objects' body-frame boxes, measured in the first world built
        try:  # one copy in each client now; the others as the slots come into use (self.use)
            for j, (lo, hi) in enumerate(groups):
                self.groups.append(WorldGroup(scene, settings, 1, capacity=hi - lo))
                self.worlds[self._first[j]] = ParticleWorld(self.groups[j].worlds[0], self.boxes)
                self.boxes = self.worlds[self._first[j]].boxes
        except BaseException:
            self.close()
            raise
        self.scene_boxes = self.worlds[0].world.aabbs()  # (M, 2, 3): as built, at the scene's poses
        self._saved: list[int] = []
        # per camera: world -> (poses, fractions) of its last ray tests (the most recent cameras)
        self._vis_caches: OrderedDict[tuple, dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]] = OrderedDict()
        self._cameras: dict[tuple, Camera] = {}
        self.scene, self.settings = scene, settings
        self.last_parts: dict[str, float] = {}
        self.last_counts: dict[str, int] = {}
        self.camera = Camera(scene.camera) if scene.camera is not None else None
        self.points = None
        if self.camera is not None:
            self._sample_points(self.worlds[0].world)
        self._active = np.array([w is not None for w in self.worlds])
        try:
            self.use(active)  # the copies in use built; one built for its client but not in use, parked
        except BaseException:
            self.close()
            raise

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

    def use(self, active: np.ndarray) -> list[int]:
        """Put the slots ``active (n,)`` bool in use (building their copies where missing) and park
        the objects of those that fall out of use; returns the slots in use, in increasing order."""
        active = np.asarray(active, bool)
        for k in np.flatnonzero(self._active & ~active).tolist():
            w = self.worlds[k].world
            dyn = [int(i) for i in w.dynamic_indices]
            w.set_poses(w.parked_pose[dyn], dyn)
            self.worlds[k].forget()
            for cache in self._vis_caches.values():
                cache.pop(k, None)
        for k in np.flatnonzero(active).tolist():
            if self.worlds[k] is None:  # its client's copies up to it
                j = self._group_of[k]
                built = len(self.groups[j].worlds)
                for c, w in enumerate(self.groups[j].grow(k - self._first[j] + 1)):
                    self.worlds[self._first[j] + built + c] = ParticleWorld(w, self.boxes)
        self._active = active.copy()
        return np.flatnonzero(active).tolist()

    def run(self, batch: BatchInput, active: np.ndarray, n_steps: int, d_sim_perc: float, lazy: bool = False,
            moving: bool = False, cameras: tuple[CameraSpec, ...] | None = None,
            freeze: bool = False, sleep_loads: bool = False) -> BatchOutput:
        """Propagate the worlds of the slots ``active (n,)`` bool from their rows of ``batch`` (one
        row per slot of the shard); the output has one row per slot in use, in increasing order of
        slot. ``last_parts`` then says where the time went (seconds: the parts of
        :data:`~estimator.worlds.propagate.PARTS` and ``visibility``), ``last_counts`` what the
        update moved (:func:`~estimator.worlds.propagate.propagate_batch`'s ``counts``)."""
        self.last_parts, self.last_counts = {}, {}
        slots = self.use(active)
        if len(slots) < len(self.worlds):
            batch = BatchInput(*(getattr(batch, f)[slots] if getattr(batch, f) is not None else None
                                 for f in PER_PARTICLE), batch.vis_query)
        if not slots:  # none of this shard's slots in use (few particles)
            M = batch.poses.shape[1]
            return BatchOutput(np.zeros((0, M, 7)), np.zeros((0, M, 6)), np.zeros((0, M), np.int8), np.zeros((0, M)),
                               np.zeros((0, M, 2, 3)), np.zeros(0, bool), np.zeros((0, M)))
        self.last_parts = parts = {}
        out = propagate_batch([self.worlds[k] for k in slots], batch, n_steps, d_sim_perc, lazy, moving, parts,
                              self.last_counts, freeze, sleep_loads)
        t0 = time.perf_counter()
        q = np.flatnonzero(batch.vis_query) if batch.vis_query is not None else np.zeros(0, int)
        if cameras is None:
            cams = [self.camera] if self.camera is not None else []
        else:
            cams = [self.camera_for(c) for c in cameras]
        if cams and len(q):  # several cameras: an object is as visible as the best of them shows it
            out.visible[:, q] = np.max([self._visibility(c, out.poses, out.finite, q, slots, out.aabbs)
                                        for c in cams], axis=0)
        parts["visibility"] = time.perf_counter() - t0
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
        slots = np.flatnonzero((np.ones(len(self.worlds), bool) if only is None else only) & self._active).tolist()
        out = np.zeros((len(cams), len(self.worlds), len(targets)), bool if threshold is not None else float)
        if not slots:
            return out
        worlds = self._ray_worlds(slots)
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

    def _ray_worlds(self, slots: list[int], reached: np.ndarray | None = None) -> list[World]:
        """The worlds of ``slots``, ready for ray tests: what was frozen there is back in collision
        detection (:meth:`~estimator.worlds.batch.ParticleWorld.thaw`; rays miss a body out of it).
        With ``reached (len(slots), M)`` bool, the boxes the coming rays' segments meet
        (:meth:`~physics.sightlines.Sightlines.reached`), only the objects it marks: the rays cannot
        hit the others, which stay out, and the next update need not freeze them again (a change of
        a body's collision filter takes it out of Bullet's world and back in)."""
        for j, k in enumerate(slots):
            pw = self.worlds[k]
            if reached is None:
                pw.thaw()
            elif pw.frozen:
                pw.thaw([i for i in pw.frozen if reached[j, i]])
        return [self.worlds[k].world for k in slots]

    def _visibility(self, camera: Camera, poses: np.ndarray, finite: np.ndarray, q: np.ndarray,
                    slots: list[int], boxes: np.ndarray | None = None) -> np.ndarray:
        """Visible fractions ``(K, len(q))`` of objects ``q`` in the worlds of ``slots`` (K of them)
        at ``poses (K, M, 7)`` (zero for exploded worlds). With ``boxes (K, M, 2, 3)``, the objects'
        world boxes (scene frame) as physics left them, the boxes and solids decide the sightlines
        they can before any ray is cast (:func:`~physics.visibility.seen_points`: the same answer
        as the rays, for fewer of them). An object keeps the answer of its world's
        last ray tests when it has not moved (bit for bit) and nothing that moved since came near its
        rays (:func:`~physics.visibility.rays_clear_of`): most of a resting scene casts no ray. With
        ``boxes``, of the objects frozen in a world only those the rays to be cast may hit are put
        back in collision detection (:meth:`_ray_worlds`); without, all of them."""
        key = camera_key(camera.spec)
        cache = self._vis_caches.pop(key, {})
        self._vis_caches[key] = cache  # the most recent last
        while len(self._vis_caches) > VISIBILITY_CACHED_CAMERAS:
            self._vis_caches.popitem(last=False)
        K, n = len(slots), len(q)
        vis = np.zeros((K, n))
        need = np.zeros((K, n), dtype=bool)
        now = poses[..., :3] + quat_rotate(poses[..., 3:], self.box_centres[None])  # (K, M, 3), at once
        fin = np.flatnonzero(finite)
        need[fin] = True
        have = [k for k in fin.tolist() if slots[k] in cache]  # worlds with an answer kept
        if have:
            old = np.stack([cache[slots[k]][0] for k in have])  # (H, M, 7)
            rows = np.stack([cache[slots[k]][1] for k in have])[:, q]  # (H, n)
            old_centres = np.stack([cache[slots[k]][2] for k in have])  # (H, M, 3)
            moved = np.any(poses[have] != old, axis=-1)  # (H, M)
            keep = ~np.isnan(rows) & ~moved[:, q]
            centres = now[have][:, q]
            for c in (old_centres, now[have]):  # nothing that moved came near its rays, before or after
                keep &= rays_clear_of(camera, centres, self.radii[q], c, self.radii, moved)
            vis[have] = np.where(keep, rows, 0.0)
            need[have] = ~keep
        todo = np.flatnonzero(need.any(axis=1)).tolist()
        if todo:
            shortcuts = {}
            ray_slots = [slots[k] for k in todo]
            if boxes is not None:  # the frozen objects the rays may meet are put back before they are cast
                convex = np.array([self.scene.objects[int(i)].shape in CONVEX_SHAPES for i in q])
                shortcuts = dict(boxes=boxes[todo], convex=convex, solids=Solids.posed(self.solids, poses[todo]),
                                 before_cast=lambda reached: self._ray_worlds(ray_slots, reached))
                worlds = [self.worlds[k].world for k in ray_slots]
            else:
                worlds = self._ray_worlds(ray_slots)
            fresh = visible_fractions(worlds, camera, q, self.points, poses[np.ix_(todo, q)], need[todo], **shortcuts)
            vis[todo] = np.where(need[todo], fresh, vis[todo])
        for k in np.flatnonzero(finite).tolist():
            row = np.full(poses.shape[1], np.nan)
            row[q] = vis[k]
            cache[slots[k]] = (poses[k].copy(), row, now[k])
        return vis

    def bare_step(self, n_steps: int, resting: bool = True) -> float:
        """Step every client ``n_steps`` times and nothing else (the benchmark's reference); returns
        the seconds the stepping took. ``resting=False``: with every object asleep taken out of
        collision detection for these steps and put back after (:meth:`~physics.world.World.set_colliding`):
        what stepping would cost if objects at rest cost nothing (a bound: what a moving object
        would have hit among them is gone too; those frozen stay out). Bullet drops their contacts,
        so the worlds do not come back exactly; the benchmark saves and restores them around the call."""
        out = []
        if not resting:
            frozen = {id(pw.world): set(pw.frozen) for pw in self.worlds if pw is not None}
            for g in self.groups:
                for w in g.worlds:
                    out_now = frozen.get(id(w), set())
                    rows = asleep(w, [i for i in w.dynamic_indices.tolist() if not w.is_parked(i) and i not in out_now])
                    w.set_colliding(rows, False)
                    out.append((w, rows))
        t0 = time.perf_counter()
        for g in self.groups:
            g.step(n_steps)
        seconds = time.perf_counter() - t0
        for w, rows in out:
            w.set_colliding(rows, True)
        return seconds

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


def _worker_main(conn, scene, settings, groups, buffer, n_particles, active):
    shard = None
    lo, hi = groups[0][0], groups[-1][1]
    try:
        shard = _Shard(scene, settings, groups, active)
        # what the worker holds once built is never garbage: kept out of the cyclic collector's full
        # collections, which otherwise scan it (about 46,000 objects, 17-20 ms, once every few dozen updates)
        gc.freeze()
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
            if msg[0] == "bare":  # the reply carries the stepping's time
                conn.send(("ok", shard.bare_step(*msg[1:])))
                continue
            if msg[0] in ("save", "restore"):
                getattr(shard, msg[0])()
                conn.send(("ok", time.perf_counter() - t0))
                continue
            _, used, n_steps, d, lazy, moving, cameras, freeze, sleep_loads = msg
            try:
                out = shard.run(shared.inputs(lo, hi), used, n_steps, d, lazy, moving, cameras, freeze, sleep_loads)
                shared.write_outputs(lo + np.flatnonzero(used), out)
                # the worker's time, its parts, what it moved
                conn.send(("ok", (time.perf_counter() - t0, shard.last_parts, shard.last_counts)))
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
