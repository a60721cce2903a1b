"""What a pinhole camera sees of the objects of a :class:`~physics.world.World`.

An object is visible in proportion to the fraction of its sample points that are inside the camera's
field of view and whose ray from the camera reaches the object before anything else. Sample points
are fixed per object, in its frame, on an ellipsoid inscribed in its local bounding box (so that they
lie on or inside spheres, cylinders and boxes alike).
"""
from __future__ import annotations

import numpy as np

from .scene import CameraSpec
from .transforms import quat_rotate
from .world import World, ray_cast


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class Camera:
    """A pinhole camera from a :class:`~physics.scene.CameraSpec` (look-at, vertical fov)."""

    def __init__(self, spec: CameraSpec):
        self.spec = spec
        self.position = np.asarray(spec.position, dtype=float)
        self.forward = _unit(np.asarray(spec.target, float) - self.position)
        up = np.asarray(spec.up, dtype=float)
        right = np.cross(self.forward, up)
        if np.linalg.norm(right) < 1e-9:  # looking straight along up: pick any perpendicular
            right = np.cross(self.forward, [1.0, 0.0, 0.0] if abs(self.forward[0]) < 0.9 else [0.0, 1.0, 0.0])
        self.right = _unit(right)
        self.up = np.cross(self.right, self.forward)
        self.tan_v = np.tan(np.radians(spec.fov_deg) / 2.0)
        self.tan_h = self.tan_v * spec.aspect

    def in_view(self, points: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: points ``(..., 3)`` inside the view frustum (between near and far)."""
        d = np.asarray(points, dtype=float) - self.position
        z = d @ self.forward
        x = d @ self.right
        y = d @ self.up
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = (z >= self.spec.near) & (z <= self.spec.far)
            ok &= np.abs(x) <= self.tan_h * z
            ok &= np.abs(y) <= self.tan_v * z
        return ok


def local_box(world: World, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre ``(3,)`` and half extents ``(3,)`` (m) of object ``index``'s bounding box in its own
    frame (its world AABB at identity orientation). The object lies within ``|half|`` of the centre."""
    pose0 = world.get_poses([index])
    ident = pose0.copy()
    ident[0, 3:] = [0.0, 0.0, 0.0, 1.0]
    world.set_poses(ident, [index])
    lo, hi = world.aabbs([index])[0]
    world.set_poses(pose0, [index])
    return 0.5 * (lo + hi) - ident[0, :3], 0.5 * (hi - lo)


def local_sample_points(world: World, index: int, n_per_axis: int = 3) -> np.ndarray:
    """Sample points ``(P, 3)`` in the frame of object ``index`` (computed from its AABB at identity);
    the first one is the box's centre."""
    centre, half = local_box(world, index)
    g = np.linspace(-1.0, 1.0, n_per_axis)
    grid = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    norms = np.linalg.norm(grid, axis=1)
    grid = grid[norms > 0] / norms[norms > 0, None]  # directions, on the unit sphere
    pts = np.vstack([np.zeros((1, 3)), 0.8 * grid])  # centre + points inside the ellipsoid
    return centre + pts * half


def visible_fraction(world: World, camera: Camera, indices, local_points: dict[int, np.ndarray],
                     poses: np.ndarray | None = None) -> np.ndarray:
    """Fraction ``(n,)`` of each object's sample points that the camera sees in one world (its
    current state); see :func:`visible_fractions`. ``poses (n, 7)``: current poses of ``indices``
    (read from the world if None)."""
    indices = [int(i) for i in np.atleast_1d(indices)]
    if poses is None:
        poses = world.get_poses(indices) if indices else np.zeros((0, 7))
    return visible_fractions([world], camera, indices, local_points, np.asarray(poses)[None])[0]


def rays_clear_of(camera: Camera, centres: np.ndarray, radii: np.ndarray, others: np.ndarray,
                  other_radii: np.ndarray) -> np.ndarray:
    """Whether the rays from the camera to objects within ``radii (n,)`` of ``centres (n, 3)`` stay
    clear of every body within ``other_radii (m,)`` of ``others (m, 3)``: bool ``(n,)``. Such a body
    cannot occlude the object (conservative: the rays lie within the object's radius of the segment
    from the camera to its centre)."""
    if len(others) == 0:
        return np.ones(len(centres), dtype=bool)
    seg = centres - camera.position  # (n, 3)
    rel = others[None, :, :] - camera.position  # (1, m, 3)
    u = np.clip(np.einsum("nmk,nk->nm", rel, seg) / np.maximum(np.einsum("nk,nk->n", seg, seg), 1e-12)[:, None],
                0.0, 1.0)
    d = np.linalg.norm(rel - u[..., None] * seg[:, None, :], axis=-1)  # (n, m) distance to the segment
    return np.all(d > radii[:, None] + other_radii[None, :], axis=1)


def segments_miss_boxes(starts: np.ndarray, ends: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether each segment ``starts -> ends (N, 3)`` misses every box ``lo, hi (N, B, 3)`` (its own
    B boxes; the slab test, boxes closed): bool ``(N,)``."""
    d = (ends - starts)[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo - starts[:, None, :]) * inv
        t1 = (hi - starts[:, None, :]) * inv
    parallel = d == 0.0  # parallel to a slab: inside it or never
    inside = (starts[:, None, :] >= lo) & (starts[:, None, :] <= hi)
    tmin = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1))
    tmax = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1))
    enter = np.maximum(tmin.max(axis=2), 0.0)
    leave = np.minimum(tmax.min(axis=2), 1.0)
    return ~np.any(enter <= leave, axis=1)


def visible_fractions(worlds: list[World], camera: Camera, indices, local_points: dict[int, np.ndarray],
                      poses: np.ndarray, need: np.ndarray | None = None, boxes: np.ndarray | None = None,
                      convex: np.ndarray | None = None) -> np.ndarray:
    """Fraction ``(G, n)`` of each object's sample points that the camera sees, in each of the G
    worlds (copies of one scene, usually sharing a client: all their rays go to pybullet in one
    batched ray test).

    Args:
        worlds: the G worlds to cast rays in (their current state); the camera is placed in each
            world's scene frame.
        camera: the camera.
        indices: object indices (n,).
        local_points: sample points per object index, in the object's frame (see
            :func:`local_sample_points`).
        poses: ``(G, n, 7)`` current link-frame poses of ``indices`` in each world (scene frame).
        need: ``(G, n)`` bool, the fractions wanted (None: all); the others are returned as 0.
        boxes: optional ``(G, B, 2, 3)`` world AABBs (scene frame, lo and hi) of every body that
            could hide the objects in each world, object indices first (B >= max index + 1; an
            object's own box is left out of its test); with ``convex (n,)`` (objects whose sample
            points lie inside a convex shape), a ray to a point of a convex object above the floor,
            from a camera above the floor, that misses every other box is seen without a ray test
            (exactly what the ray test would say: nothing else is on the segment).
    """
    indices = [int(i) for i in np.atleast_1d(indices)]
    G, n = len(worlds), len(indices)
    if n == 0 or G == 0:
        return np.zeros((G, n))
    counts = np.array([len(local_points[i]) for i in indices])
    P = int(counts.max())
    local = np.zeros((n, P, 3))
    valid = np.zeros((n, P), dtype=bool)
    for k, i in enumerate(indices):
        local[k, :counts[k]] = local_points[i]
        valid[k, :counts[k]] = True
    poses = np.asarray(poses, dtype=float).reshape(G, n, 7)
    q = np.broadcast_to(poses[:, :, None, 3:], (G, n, P, 4))
    pts = poses[:, :, None, :3] + quat_rotate(q, np.broadcast_to(local, (G, n, P, 3)))  # (G, n, P, 3)
    sel = camera.in_view(pts) & valid
    if need is not None:
        sel &= np.asarray(need, dtype=bool)[:, :, None]
    seen = np.zeros((G, n, P), dtype=bool)
    if sel.any() and boxes is not None and convex is not None and camera.position[2] > 0:
        g_idx, o_idx, _ = np.nonzero(sel)
        p_sel = pts[sel]
        lo = boxes[g_idx, :, 0].copy()
        hi = boxes[g_idx, :, 1].copy()
        own = np.asarray(indices)[o_idx]
        lo[np.arange(len(own)), own] = 1e9  # a point far away: the object does not hide itself
        hi[np.arange(len(own)), own] = 1e9
        clear = segments_miss_boxes(np.broadcast_to(camera.position, p_sel.shape), p_sel, lo - 1e-3, hi + 1e-3)
        clear &= np.asarray(convex, dtype=bool)[o_idx] & (p_sel[:, 2] > 0)
        rows = np.flatnonzero(sel.ravel())[clear]
        seen.reshape(-1)[rows] = True
        sel = sel.copy()
        sel.reshape(-1)[rows] = False
    if sel.any():
        g_idx, o_idx, _ = np.nonzero(sel)
        origins = np.array([w.origin for w in worlds])[g_idx]
        start = camera.position + origins
        ends = start + (pts[sel] - camera.position) * 1.05  # a little beyond the point: the object is hit
        uids = np.array([[w.uids[i] for i in indices] for w in worlds])
        hit = np.empty(len(ends), dtype=np.int64)
        clients = np.array([w.client for w in worlds])[g_idx]
        for c in np.unique(clients).tolist():
            rows = np.flatnonzero(clients == c)
            hit[rows] = ray_cast(c, start[rows], ends[rows])[0]
        seen[sel] = hit == uids[g_idx, o_idx]
    return seen.sum(axis=2) / np.maximum(counts, 1)
