"""How deep objects are inside the static geometry of a scene (the table, walls, the floor), and where a
path that enters it must stop.

A particle filter of physics worlds must never believe an impossible state: an object sunk into the
table, or a free object under the floor. :class:`StaticGeometry` measures that for any stack of poses,
in a world of its own that holds the scene's static bodies and one copy of each dynamic object: the
depth of an object is the deepest penetration pybullet's closest-point query finds between it and any
static body or the floor (0 where it is clear of them, or merely touching). :meth:`StaticGeometry.clip`
stops straight paths (an object carried by a hand, moved by a tracker's detection) at the surface of
the static geometry they would enter: a sweep test done as a bisection of the path.

Units: metres; poses ``(..., 7)`` are positions and quaternions ``(x, y, z, w)`` of each object's link
frame in the scene frame, as everywhere else.
"""
from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from .scene import Scene
from .settings import PhysicsSettings
from .transforms import quat_normalize, quat_to_matrix
from .world import PARK_DEPTH, World

INVARIANT_DEPTH = 0.01
"""m: an object deeper than this inside static geometry (or a free object deeper under the floor) is in
an impossible state (soft contacts and a tracker's sunk detections stay well under it)."""

CLIP_DEPTH = 0.004
"""m: :meth:`StaticGeometry.clip` leaves a path alone unless its end is deeper than this inside static
geometry (a held box resting on the table, its detection a few millimetres low, is not moved), and
stops it where it is at most this deep."""

BISECTIONS = 8
"""Halvings of a path in :meth:`StaticGeometry.clip`: the stop is found to within 1/256 of the path."""


class StaticGeometry:
    """The static bodies of ``scene`` and one copy of each dynamic object, to query penetration depths.

    Use as a context manager (it owns a pybullet client). Objects are moved one at a time to the poses
    asked about and parked again after; static bodies never move. Collisions between dynamic objects
    are not measured (they are physics' business).
    """

    def __init__(self, scene: Scene, settings: PhysicsSettings | None = None):
        base = settings or PhysicsSettings()
        self.scene = scene
        self.world = w = World(scene, PhysicsSettings(time_step=base.time_step, gravity=base.gravity,
                                                      collision_only=True, sleeping=False))
        try:
            self.static_uids = [w.uids[i] for i in np.flatnonzero(w.static)]
            if w.floor_uid >= 0:
                self.static_uids.append(w.floor_uid)
            boxes = [pb.getAABB(u, -1, physicsClientId=w.client) for u in self.static_uids]
            self._static_lo = np.array([b[0] for b in boxes], dtype=float).reshape(-1, 3)
            self._static_hi = np.array([b[1] for b in boxes], dtype=float).reshape(-1, 3)
            if w.floor_uid >= 0:  # the plane z = 0: its box is everything under it
                self._static_lo[-1] = -np.inf
                self._static_hi[-1] = [np.inf, np.inf, 0.0]
            # each dynamic object's box in its link frame (centre, half extents), for the prefilter
            self._local = {}
            self._round = {int(m): scene.objects[int(m)].shape == "sphere" for m in w.dynamic_indices}
            # per object and margin, the last depth_of call's (pose, bodies) -> depth
            self._depths: dict[tuple[int, float], dict[tuple, float]] = {}
            for m in w.dynamic_indices:
                pose = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]])
                w.set_poses(pose, [int(m)])
                lo, hi = w.aabbs([int(m)])[0]
                self._local[int(m)] = (0.5 * (lo + hi), 0.5 * (hi - lo))
            w.set_poses(w.parked_pose[w.dynamic_indices], w.dynamic_indices)
            # the same boxes as plain floats, for one pose at a time (clear_of_static)
            self._static_boxes = list(zip(self._static_lo.tolist(), self._static_hi.tolist()))
            self._local_lists = {m: (c.tolist(), h.tolist()) for m, (c, h) in self._local.items()}
        except BaseException:
            w.close()
            raise

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> "StaticGeometry":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- queries --------------------------------------------------------------------------------------
    def box(self, m: int, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A box ``lo, hi (N, 3)`` (m) that holds dynamic object ``m`` at each of the link-frame
        ``poses (N, 7)``: its link-frame box turned with the pose (the box of its eight corners),
        or for a sphere its own box."""
        centre, half = self._local[m]
        poses = np.asarray(poses, dtype=float).reshape(-1, 7)
        if self._round[m]:
            return poses[:, :3] + centre - half, poses[:, :3] + centre + half
        R = quat_to_matrix(poses[:, 3:])  # (N, 3, 3)
        mid = poses[:, :3] + R @ centre
        ext = np.abs(R) @ half
        return mid - ext, mid + ext

    def _candidates(self, m: int, poses: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """``(N, S)`` bool: which static bodies, their boxes shrunk by ``margin`` (m), the box of object
        ``m`` at ``poses (N, 7)`` overlaps (:meth:`box`: a superset of the bodies it is more than
        ``margin`` deep into)."""
        lo, hi = self.box(m, poses)
        return np.all((lo[:, None, :] <= self._static_hi[None] - margin)
                      & (hi[:, None, :] >= self._static_lo[None] + margin), axis=2)

    def clear_of_static(self, m: int, pose: list[float], margin: float) -> bool:
        """Whether the box of dynamic object ``m`` (:meth:`box`) at the one link-frame ``pose`` (7
        floats) overlaps no static body's box shrunk by ``margin`` (m): then it cannot be more than
        ``margin`` deep inside static geometry (:meth:`depth_of` is 0). The box test of
        :meth:`depth_of` for one pose, in plain floats: a detection that every particle shares is
        asked about at every update, and numpy's overhead on one pose was most of that question's
        cost. A non-finite pose or a zero quaternion is not clear."""
        x, y, z, qx, qy, qz, qw = pose
        if not all(math.isfinite(v) for v in pose):
            return False
        centre, half = self._local_lists[m]
        if self._round[m]:
            mid, ext = [x + centre[0], y + centre[1], z + centre[2]], half
        else:
            n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
            if n == 0.0:
                return False
            qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
            rows = ((1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)),
                    (2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)),
                    (2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)))
            mid = [p + (r[0] * centre[0] + r[1] * centre[1] + r[2] * centre[2]) for p, r in zip((x, y, z), rows)]
            ext = [abs(r[0]) * half[0] + abs(r[1]) * half[1] + abs(r[2]) * half[2] for r in rows]
        lo = [a - e for a, e in zip(mid, ext)]
        hi = [a + e for a, e in zip(mid, ext)]
        for s_lo, s_hi in self._static_boxes:
            if all(lo[a] <= s_hi[a] - margin and hi[a] >= s_lo[a] + margin for a in range(3)):
                return False
        return True

    def may_be_inside(self, aabbs: np.ndarray, depth: float = INVARIANT_DEPTH) -> np.ndarray:
        """``(...)`` bool: which world bounding boxes ``aabbs (..., 2, 3)`` (m, ``[min, max]``; Bullet's,
        a little larger than the shapes) overlap a static body's box, or the floor, by more than
        ``depth`` (m) on every axis: a superset of the objects that can be that deep inside static
        geometry, found without a query per object."""
        lo, hi = np.asarray(aabbs, dtype=float)[..., 0, :], np.asarray(aabbs, dtype=float)[..., 1, :]
        if len(self._static_lo) == 0:
            return np.zeros(lo.shape[:-1], dtype=bool)
        over = (lo[..., None, :] <= self._static_hi - depth) & (hi[..., None, :] >= self._static_lo + depth)
        return np.any(np.all(over, axis=-1), axis=-1)

    def depth_of(self, m: int, poses: np.ndarray, beyond: float = 0.0) -> np.ndarray:
        """Penetration depths ``(N,)`` (m, >= 0) of dynamic object ``m`` at link-frame ``poses (N, 7)``
        into the static bodies and the floor; 0 for non-finite and parked poses, and (skipped by the
        box test) for poses that cannot be more than ``beyond`` (m) deep."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 7)
        if len(poses) > 1 and np.all(poses == poses[:1]):  # one pose for all (a detection every particle
            return np.full(len(poses), self.depth_of(m, poses[:1], beyond)[0])  # shares): tested once
        if len(poses) == 1 and poses[0, 2] > -PARK_DEPTH and self.clear_of_static(m, poses[0].tolist(), beyond):
            return np.zeros(1)  # its box meets no static body's: not that deep, whatever the pose
        w = self.world
        out = np.zeros(len(poses))
        ok = np.all(np.isfinite(poses), axis=1) & (poses[:, 2] > -PARK_DEPTH)
        if not np.any(ok):
            return out
        cand = np.zeros((len(poses), len(self.static_uids)), dtype=bool)
        cand[ok] = self._candidates(m, poses[ok], beyond)
        rows = np.flatnonzero(cand.any(axis=1))
        if len(rows) == 0:
            return out
        com = w.com_frame(poses[rows][:, None], None, [m])[0][:, 0]
        com[:, 3:] = quat_normalize(com[:, 3:])
        c, uid, statics = w.client, w.uids[m], self.static_uids
        reset, closest = pb.resetBasePositionAndOrientation, pb.getClosestPoints
        # equal poses are asked once: many particles share a detection, and an object at rest keeps
        # its pose from one update to the next, so the answers of the last call with the same object
        # and margin are kept (the depth of a pose does not change; memory: one call's poses)
        last = self._depths.get((m, beyond), {})
        done: dict[tuple, float] = {}
        moved = False
        for r, row, which in zip(rows.tolist(), com.tolist(), cand[rows].tolist()):
            key = (*row, *which)  # the pose, and the bodies its depth is measured into
            if key in done:
                out[r] = done[key]
                continue
            if key in last:
                out[r] = done[key] = last[key]
                continue
            reset(uid, row[:3], row[3:], physicsClientId=c)
            moved = True
            worst = 0.0
            for s, hit in zip(statics, which):
                if hit:
                    for pt in closest(uid, s, 0.0, physicsClientId=c):
                        if pt[8] < worst:
                            worst = pt[8]
            out[r] = done[key] = -worst
        if moved:
            reset(uid, w.parked_pose[m, :3].tolist(), [0.0, 0.0, 0.0, 1.0], physicsClientId=c)
        self._depths[(m, beyond)] = done
        return out

    def depths(self, poses: np.ndarray, objects: np.ndarray | None = None) -> np.ndarray:
        """Penetration depths ``(..., M)`` (m, >= 0) of the objects at ``poses (..., M, 7)`` into the
        static bodies and the floor. Only the dynamic objects among ``objects (M,)`` bool (default:
        all dynamic ones) are measured; the others, non-finite poses and parked ones (an object not
        known yet, :class:`~physics.world.World`) get 0."""
        poses = np.asarray(poses, dtype=float)
        w = self.world
        M = w.num_objects
        if poses.shape[-2:] != (M, 7):
            raise ValueError(f"poses must have shape (..., {M}, 7), got {poses.shape}")
        flat = poses.reshape(-1, M, 7)
        out = np.zeros(flat.shape[:2])
        which = ~w.static if objects is None else (np.asarray(objects, dtype=bool) & ~w.static)
        for m in np.flatnonzero(which).tolist():
            out[:, m] = self.depth_of(m, flat[:, m])
        return out.reshape(poses.shape[:-1])

    def violations(self, poses: np.ndarray, objects: np.ndarray | None = None,
                   depth: float = INVARIANT_DEPTH) -> np.ndarray:
        """``(..., M)`` bool: objects deeper than ``depth`` (m) inside static geometry or the floor
        (see :meth:`depths`)."""
        return self.depths(poses, objects) > depth

    # -- paths ----------------------------------------------------------------------------------------
    def clip(self, m: int, start: np.ndarray, end: np.ndarray, depth: float = CLIP_DEPTH) -> tuple[np.ndarray, np.ndarray]:
        """Straight paths of dynamic object ``m`` from link-frame poses ``start`` to ``end`` ``(N, 7)``
        (position linear, orientation normalised-linear), stopped where they enter static geometry:
        a sweep test.

        Each path whose swept box meets a static body's is sampled every :meth:`spacing` (so that it
        cannot step over a table top) and its first entry (a sample deeper than ``depth`` after a
        clear one) is found; the path then ends at the last point found clear between the two
        (:data:`BISECTIONS` halvings): the object stops at the surface, as a carried object stops on
        the table a hand pushes it down onto. A path that starts inside and leaves is kept; one
        inside from its start to its end has its end pushed out along the deepest contact's normal.
        Returns the new ends ``(N, 7)`` and the fraction
        of each path kept ``(N,)`` (1 where it is kept; NaN where the end was pushed out)."""
        start = np.asarray(start, dtype=float).reshape(-1, 7)
        end = np.asarray(end, dtype=float).reshape(-1, 7).copy()
        frac = np.ones(len(end))
        ok = np.all(np.isfinite(start), axis=1) & np.all(np.isfinite(end), axis=1) & (
            np.minimum(start[:, 2], end[:, 2]) > -PARK_DEPTH)
        rows = np.flatnonzero(ok)
        if len(rows) == 0:
            return end, frac
        swept = self._candidates(m, start[rows], depth) | self._candidates(m, end[rows], depth)
        box_lo = np.minimum(start[rows, :3], end[rows, :3])
        box_hi = np.maximum(start[rows, :3], end[rows, :3])
        reach = float(np.linalg.norm(self._local[m][1]) + np.linalg.norm(self._local[m][0]))
        long = np.linalg.norm(end[rows, :3] - start[rows, :3], axis=1) > self.spacing(m)
        swept |= long[:, None] & np.all((box_lo[:, None, :] - reach <= self._static_hi[None] - depth)
                                        & (box_hi[:, None, :] + reach >= self._static_lo[None] + depth), axis=2)
        rows = rows[swept.any(axis=1)]
        if len(rows) == 0:
            return end, frac
        # first pass: every path sampled every `spacing`, all in one query
        step = self.spacing(m)
        counts = np.minimum(64, np.maximum(1, np.ceil(np.linalg.norm(end[rows, :3] - start[rows, :3], axis=1)
                                                      / step))).astype(int)
        owner = np.repeat(np.arange(len(rows)), counts + 1)
        fs = np.concatenate([np.arange(n + 1) / n for n in counts.tolist()])
        d = self.depth_of(m, _along(start[rows[owner]], end[rows[owner]], fs), depth)
        bad = d > depth
        # the first entry into static geometry of each path: a bad sample after a clear one (a path
        # that starts inside, e.g. a perturbed start, and leaves is no entry)
        entry = bad & np.concatenate([[False], ~bad[:-1] & (owner[1:] == owner[:-1])])
        first = np.full(len(rows), -1)
        for j in np.flatnonzero(entry)[::-1].tolist():
            first[owner[j]] = j
        hit = first >= 0
        last = np.cumsum(counts + 1) - 1  # each path's end sample
        starts_in = ~hit & bad[last]  # inside all along to its end: its end goes out along the normal
        pushed: dict[bytes, np.ndarray] = {}  # equal ends (a detection every particle shares) once
        for j in np.flatnonzero(starts_in).tolist():
            r = rows[j]
            key = end[r].tobytes()
            if key not in pushed:
                pushed[key] = self._push_out(m, end[r])
            end[r] = pushed[key]
            frac[r] = np.nan
        walk = np.flatnonzero(hit)
        if len(walk):  # bisection between the last clear sample and the first bad one, all paths at once
            lo, hi = fs[first[walk] - 1], fs[first[walk]]
            r = rows[walk]
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                worse = self.depth_of(m, _along(start[r], end[r], mid), depth) > depth
                hi = np.where(worse, mid, hi)
                lo = np.where(worse, lo, mid)
            end[r] = _along(start[r], end[r], lo)
            frac[r] = lo
        return end, frac

    def spacing(self, m: int) -> float:
        """Sample spacing (m) of :meth:`clip` for object ``m``: its smallest half extent, at least
        5 mm (a table top 5 cm thick cannot fall between two samples of anything larger)."""
        return max(0.005, float(np.min(self._local[m][1])))

    def push_out(self, m: int, poses: np.ndarray, depth: float = INVARIANT_DEPTH) -> tuple[np.ndarray, np.ndarray]:
        """Link-frame ``poses (N, 7)`` of dynamic object ``m``, those deeper than ``depth`` (m) inside
        static geometry moved out of it along the deepest contact's normal (a fast object caught by
        a step in the middle of its impact on the table). Equal poses (a detection every particle
        shares) are pushed out once, and one whose box meets no static body's is not measured at all
        (:meth:`clear_of_static`: a detection of an object on the table, asked about at every update).
        Returns the poses ``(N, 7)`` (a copy) and which were moved ``(N,)``."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 7).copy()
        if len(poses) and poses[0, 2] > -PARK_DEPTH and np.all(poses == poses[:1]) and self.clear_of_static(
                m, poses[0].tolist(), depth):
            return poses, np.zeros(len(poses), dtype=bool)
        deep = self.depth_of(m, poses, depth) > depth
        pushed: dict[bytes, np.ndarray] = {}
        for r in np.flatnonzero(deep).tolist():
            key = poses[r].tobytes()
            if key not in pushed:
                pushed[key] = self._push_out(m, poses[r])
            poses[r] = pushed[key]
        return poses, deep

    def static_top(self, bodies) -> np.ndarray:
        """Heights (m) of the tops of the boxes of the static bodies ``bodies`` (indices into
        :attr:`static_uids`; the floor's is 0)."""
        return self._static_hi[np.asarray(bodies, dtype=int), 2]

    def near_static(self, m: int, poses: np.ndarray, margin: float) -> np.ndarray:
        """``(N, S)`` bool: the static bodies whose boxes come within ``margin`` (m) of the box of
        dynamic object ``m`` (:meth:`box`) at each of the link-frame ``poses (N, 7)``."""
        return self._candidates(m, np.asarray(poses, dtype=float).reshape(-1, 7), -margin)

    def under(self, m: int, poses: np.ndarray, reach: float) -> np.ndarray:
        """What static geometry holds dynamic object ``m`` up at each of the link-frame ``poses (N,
        7)``: rays straight down from the top of its box (:meth:`box`), at the box's centre and its
        four corners, to ``reach`` (m) under its bottom. ``(N, 5, 5)``: per pose and ray, ``[static
        body (its index in :attr:`static_uids`; -1: none within reach), height of the hit (m), normal
        there (3)]`` (NaN where none). The dynamic objects' copies are parked far away: only static
        bodies are hit."""
        lo, hi = self.box(m, poses)
        mid = 0.5 * (lo + hi)
        xy = np.stack([mid[:, :2], lo[:, :2], np.stack([lo[:, 0], hi[:, 1]], axis=-1),
                       np.stack([hi[:, 0], lo[:, 1]], axis=-1), hi[:, :2]], axis=1)  # (N, 5, 2)
        n = len(lo)
        top = np.broadcast_to(hi[:, None, 2:], (n, 5, 1))
        bottom = np.broadcast_to(lo[:, None, 2:] - reach, (n, 5, 1))
        starts = np.concatenate([xy, top], axis=-1).reshape(-1, 3).tolist()
        ends = np.concatenate([xy, bottom], axis=-1).reshape(-1, 3).tolist()
        index = {u: i for i, u in enumerate(self.static_uids)}
        out = np.full((n * 5, 5), np.nan)
        out[:, 0] = -1
        for r, hit in enumerate(pb.rayTestBatch(starts, ends, physicsClientId=self.world.client)):
            if hit[0] in index:
                out[r] = [index[hit[0]], hit[3][2], *hit[4]]
        return out.reshape(n, 5, 5)

    def _push_out(self, m: int, pose: np.ndarray, rounds: int = 3) -> np.ndarray:
        """``pose (7,)`` moved out of the static geometry it is inside of, along the deepest contact's
        normal, by the contact's depth (a few rounds: a corner may touch two bodies)."""
        w = self.world
        c, uid = w.client, w.uids[m]
        pose = pose.copy()
        for _ in range(rounds):
            com = w.com_frame(pose[None, None], None, [m])[0][0, 0]
            pb.resetBasePositionAndOrientation(uid, com[:3].tolist(), quat_normalize(com[3:]).tolist(),
                                               physicsClientId=c)
            worst, normal = 0.0, None
            for s in self.static_uids:
                for pt in pb.getClosestPoints(uid, s, 0.0, physicsClientId=c):
                    if pt[8] < worst:
                        worst, normal = pt[8], pt[7]  # normal on B (the static body), from B to A
            if normal is None or worst > -1e-4:
                break
            pose[:3] += np.asarray(normal) * (-worst + 1e-4)
        pb.resetBasePositionAndOrientation(uid, w.parked_pose[m, :3].tolist(), [0.0, 0.0, 0.0, 1.0],
                                           physicsClientId=c)
        return pose


def _along(start: np.ndarray, end: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Poses ``(N, 7)`` a fraction ``f (N,)`` of the way from ``start`` to ``end`` ``(N, 7)``:
    position linear, orientation normalised-linear along the shorter arc."""
    f = np.asarray(f, dtype=float)[:, None]
    out = start + f * (end - start)
    q0, q1 = start[:, 3:], end[:, 3:]
    q1 = np.where(np.sum(q0 * q1, axis=1, keepdims=True) < 0, -q1, q1)
    out[:, 3:] = quat_normalize(q0 + f * (q1 - q0))
    return out
