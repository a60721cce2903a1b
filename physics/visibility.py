"""What a pinhole camera sees of the objects of a :class:`~physics.world.World`.

An object is visible in proportion to the fraction of its sample points that are inside the camera's
field of view and whose ray from the camera reaches the object before anything else. Sample points
are fixed per object, in its frame, on an ellipsoid inscribed in its local bounding box (so that they
lie on or inside spheres, cylinders and boxes alike).

A point's ray test is skipped where boxes decide it as the ray test would: the segment misses every
other body's bounding box (seen), or it goes through a box that lies inside another body before it
can reach its own object (hidden); other rays are first cast only as far as their object's box.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pybullet as pb

from .scene import CameraSpec
from .sightlines import SOLID_DEPTH, Sightlines, Solids
from .transforms import cross, quat_rotate
from .world import World


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class Camera:
    """A pinhole camera from a :class:`~physics.scene.CameraSpec` (look-at, vertical fov)."""

    def __init__(self, spec: CameraSpec):
        self.spec = spec
        self.position = np.asarray(spec.position, dtype=float)
        self.forward = _unit(np.asarray(spec.target, float) - self.position)
        up = np.asarray(spec.up, dtype=float)
        right = cross(self.forward, up)  # np.cross's bits, without its overhead (a search builds many)
        if np.linalg.norm(right) < 1e-9:  # looking straight along up: pick any perpendicular
            right = cross(self.forward, np.array([1.0, 0.0, 0.0] if abs(self.forward[0]) < 0.9 else [0.0, 1.0, 0.0]))
        self.right = _unit(right)
        self.up = cross(self.right, self.forward)
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


def solid_box(world: World, index: int, box: tuple[np.ndarray, np.ndarray] | None = None
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """A box inside object ``index`` when its collision shape is one box, axis-aligned in its frame
    (pybullet's primitive boxes, URDFs such as pybullet_data's table): centre ``(3,)`` and half
    extents ``(3,)`` (m) in the object's frame, :data:`SOLID_DEPTH` inside its faces; None for any
    other shape (or a box thinner than twice that). ``box``: the object's :func:`local_box`, if
    already read."""
    uid, c = world.uids[index], world.client
    if pb.getNumJoints(uid, physicsClientId=c):
        return None
    data = pb.getCollisionShapeData(uid, -1, physicsClientId=c)
    if len(data) != 1 or data[0][2] != pb.GEOM_BOX:
        return None
    centre, half = local_box(world, index) if box is None else box
    dims = 0.5 * np.asarray(data[0][3], dtype=float)
    if not np.all(np.abs(half - dims) < 1.5e-3):  # the box, not turned in the object's frame
        return None
    inner = dims - SOLID_DEPTH
    return (centre, inner) if np.all(inner > 0) else None


def first_copies(poses: np.ndarray) -> np.ndarray:
    """For each of K particles ``poses (K, ...)``, the index ``(K,)`` of the first particle whose
    poses are all equal to its own, bit for bit (itself when none before it is): worlds holding
    such copies see the same, so only the first needs its ray tests."""
    first: dict[bytes, int] = {}
    rows = np.ascontiguousarray(poses).reshape(len(poses), -1)
    return np.array([first.setdefault(r.tobytes(), k) for k, r in enumerate(rows)], dtype=int)


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
                  other_radii: np.ndarray, moved: np.ndarray | None = None) -> np.ndarray:
    """Whether the rays from the camera to objects within ``radii (n,)`` of ``centres (..., n, 3)``
    stay clear of every body within ``other_radii (m,)`` of ``others (..., m, 3)``: bool ``(..., n)``
    (leading axes: several worlds at once). With ``moved (..., m)`` bool, only those bodies count.
    Such a body cannot occlude the object (conservative: the rays lie within the object's radius of
    the segment from the camera to its centre)."""
    centres, others = np.asarray(centres, dtype=float), np.asarray(others, dtype=float)
    if others.shape[-2] == 0:
        return np.ones(centres.shape[:-1], dtype=bool)
    seg = centres - camera.position  # (..., n, 3)
    rel = others - camera.position  # (..., m, 3)
    u = np.clip(np.einsum("...mk,...nk->...nm", rel, seg)
                / np.maximum(np.einsum("...nk,...nk->...n", seg, seg), 1e-12)[..., None], 0.0, 1.0)
    d = np.linalg.norm(rel[..., None, :, :] - u[..., None] * seg[..., :, None, :], axis=-1)  # (..., n, m)
    clear = d > radii[:, None] + other_radii[None, :]
    if moved is not None:
        clear |= ~np.asarray(moved, bool)[..., None, :]
    return np.all(clear, axis=-1)


def visible_fractions(worlds: list[World], camera: Camera, indices, local_points: dict[int, np.ndarray],
                      poses: np.ndarray, need: np.ndarray | None = None, boxes: np.ndarray | None = None,
                      convex: np.ndarray | None = None, solids: Solids | None = None,
                      before_cast: Callable[[np.ndarray], None] | None = None) -> np.ndarray:
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
        solids: with ``boxes``, boxes inside objects (:func:`seen_points`): a sightline through
            another object's solid before it reaches its own object's box is hidden, without a ray.
        before_cast: with ``boxes``, called before the ray tests with the ``(G, B)`` bool of the
            boxes their segments meet (:meth:`~physics.sightlines.Sightlines.reached`): the bodies
            they can hit, which must then be in collision detection (see :func:`seen_points`).
    """
    seen, counts = seen_points(worlds, [camera], indices, local_points, poses, need, boxes, convex, solids=solids,
                               before_cast=before_cast)
    return seen[0] / np.maximum(counts, 1)


def visible_enough(worlds: list[World], cameras: list[Camera], indices, local_points: dict[int, np.ndarray],
                   poses: np.ndarray, threshold: float, boxes: np.ndarray | None = None,
                   convex: np.ndarray | None = None, solids: Solids | None = None) -> np.ndarray:
    """Bool ``(V, G, n)``: whether each of the V ``cameras`` sees at least ``threshold`` of each
    object's sample points in each of the G worlds; exactly ``visible_fractions(worlds, camera, ...)
    >= threshold`` camera by camera (arguments as there, and ``solids`` as :func:`seen_points`),
    for fewer tests: each particle's points are tested in rounds until its answer is decided
    (reached, or out of reach with the points left)."""
    counts = _point_counts(indices, local_points)
    c = np.maximum(counts, 1)
    steps = np.arange(int(counts.max(initial=0)) + 2)
    reach = steps[None, :] / c[:, None] >= threshold  # (n, P + 2): j seen points make the threshold
    reach[np.arange(len(counts)), counts + 1] = True  # at most counts[o] can be seen: c + 1 never
    required = np.argmax(reach, axis=1)  # the fewest seen points that make the threshold
    seen, _ = seen_points(worlds, cameras, indices, local_points, poses, None, boxes, convex, required, solids)
    return seen >= required


def _point_counts(indices, local_points: dict[int, np.ndarray]) -> np.ndarray:
    return np.array([len(local_points[int(i)]) for i in np.atleast_1d(indices)], dtype=int)


LAST_ROUND_RAYS = 100
"""When at most this many rays could still be needed, :func:`seen_points` casts them all at once."""


def seen_points(worlds: list[World], cameras: list[Camera], indices, local_points: dict[int, np.ndarray],
                poses: np.ndarray, need: np.ndarray | None = None, boxes: np.ndarray | None = None,
                convex: np.ndarray | None = None, required: np.ndarray | None = None,
                solids: Solids | None = None,
                before_cast: Callable[[np.ndarray], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Number of each object's sample points that each camera sees in each world ``(V, G, n)``
    (int), and each object's number of sample points ``(n,)``; arguments as
    :func:`visible_fractions`, for V ``cameras`` (all their rays of a client go to pybullet in one
    batched ray test).

    Boxes decide what they can, for all points at once (:class:`~physics.sightlines.Sightlines`):
    with ``boxes`` and ``convex``, a segment that misses every other box is seen; with ``boxes``
    and ``solids`` (boxes inside objects, :func:`solid_box`), one that goes through another
    object's solid before it enters its own object's box (1 mm wider: the object can only be hit
    inside it, the solid's object surely is before) is hidden. The other points get ray tests, with
    ``boxes`` first a short one, as far as the ray enters its object's box: a body hit there hides
    the point (such a ray costs a fraction of the whole one, cast only when nothing is hit).
    With ``required (n,)`` (int), a count is exact only as far as it says whether it reaches
    ``required``: rays are cast in rounds, each of as many as a count needs to be decided either
    way (none is wasted: a count is never decided before its round's last ray), until every count
    has reached ``required`` or can no longer reach it. ``before_cast(reached)``: called before each
    batch of ray tests, with ``boxes``, with the boxes their segments meet ``(G, B)`` bool (a body
    out of collision detection is missed by rays: a caller that keeps bodies out can put back only
    those)."""
    indices = [int(i) for i in np.atleast_1d(indices)]
    G, n, V = len(worlds), len(indices), len(cameras)
    counts = _point_counts(indices, local_points)
    if n == 0 or G == 0 or V == 0:
        return np.zeros((V, G, n), dtype=int), counts
    P = int(counts.max())
    local = np.zeros((n, P, 3))
    valid = np.zeros((n, P), dtype=bool)
    for k, i in enumerate(indices):
        local[k, :counts[k]] = local_points[i]
        valid[k, :counts[k]] = True
    poses = np.asarray(poses, dtype=float).reshape(G, n, 7)
    q = np.broadcast_to(poses[:, :, None, 3:], (G, n, P, 4))
    pts = poses[:, :, None, :3] + quat_rotate(q, np.broadcast_to(local, (G, n, P, 3)))  # (G, n, P, 3)
    sel = np.array([c.in_view(pts) for c in cameras]) & valid  # (V, G, n, P)
    if need is not None:
        sel &= np.asarray(need, dtype=bool)[None, :, :, None]
    seen = np.zeros((V, G, n), dtype=int)
    rays = Sightlines(worlds, indices, np.array([c.position for c in cameras]), pts, boxes, convex, solids)
    if sel.any():  # the boxes first, all points at once (cheap), then rays for the others
        clear = rays.clear(sel)
        seen += clear.sum(axis=-1)
        sel &= ~(clear | rays.hidden_by_solids(sel & ~clear))
    def cast(mask: np.ndarray) -> np.ndarray:  # the ray tests, the caller told first what they may hit
        if before_cast is not None and boxes is not None and mask.any():
            before_cast(rays.reached(mask))
        return rays.cast(mask)

    if required is None:
        return seen + cast(sel).sum(axis=-1), counts
    required = np.asarray(required, dtype=int)
    while True:
        left = sel.sum(axis=-1)
        open_ = (seen < required) & (seen + left >= required)  # (V, G, n): not decided yet
        if not open_.any():
            return seen, counts
        # as many rays as are needed to decide either way, whatever they say: none is wasted (a
        # few left: all of them, as a round costs as much as a hundred rays)
        k = np.where(open_, np.minimum(required - seen, left - (required - seen) + 1), 0)
        k = np.where(open_, left, 0) if left[open_].sum() <= LAST_ROUND_RAYS else k
        pick = sel & (np.cumsum(sel, axis=-1) <= k[..., None])
        seen += cast(pick).sum(axis=-1)
        sel &= ~pick


def sphere_occlusion(eye: np.ndarray, centres: np.ndarray, radii: np.ndarray, occluders: np.ndarray,
                     occluder_radius: float) -> np.ndarray:
    """Fraction ``(...)`` of each object's apparent disk, seen from ``eye (3,)``, that spheres of
    radius ``occluder_radius`` (m) at ``occluders (H, 3)`` cover from in front of it.

    Objects are balls of ``radii (...)`` (m) at ``centres (..., 3)``; on the view sphere around the
    eye each is a disk of angular radius ``asin(r / d)``, and so is each occluder. An occluder covers
    the part of an object's disk its own disk overlaps (the area of two overlapping circles, small
    angles), if its front is nearer the eye than the object's centre; several occluders count with
    the largest share any one covers. Used for a tracked hand, which the particle worlds do not
    contain: what it hides of the object it holds, or of anything behind it."""
    eye = np.asarray(eye, dtype=float)
    centres = np.asarray(centres, dtype=float)
    radii = np.asarray(radii, dtype=float)
    occluders = np.asarray(occluders, dtype=float).reshape(-1, 3)
    out = np.zeros(centres.shape[:-1])
    if len(occluders) == 0 or occluder_radius <= 0:
        return out
    to_obj = centres - eye
    d_obj = np.linalg.norm(to_obj, axis=-1)
    a_obj = np.arcsin(np.clip(radii / np.maximum(d_obj, 1e-9), 0.0, 1.0))
    for h in occluders:
        to_h = h - eye
        d_h = float(np.linalg.norm(to_h))
        if d_h <= occluder_radius:  # the eye inside the hand: it sees nothing
            out = np.maximum(out, 1.0)
            continue
        a_h = math.asin(occluder_radius / d_h)
        cos = np.einsum("...k,k->...", to_obj, to_h) / np.maximum(d_obj * d_h, 1e-12)
        theta = np.arccos(np.clip(cos, -1.0, 1.0))
        share = _disk_overlap(a_obj, a_h, theta) / np.maximum(np.pi * a_obj ** 2, 1e-18)
        in_front = d_h - occluder_radius < d_obj
        out = np.maximum(out, np.where(in_front, np.clip(share, 0.0, 1.0), 0.0))
    return out


def _disk_overlap(r1: np.ndarray, r2: float, d: np.ndarray) -> np.ndarray:
    """Area of the overlap of disks of radii ``r1 (...)`` and ``r2`` whose centres are ``d (...)``
    apart (planar formula)."""
    r1 = np.asarray(r1, dtype=float)
    d = np.asarray(d, dtype=float)
    out = np.zeros(np.broadcast(r1, d).shape)
    small = np.minimum(r1, r2)
    inside = d <= np.abs(r1 - r2)
    out = np.where(inside, np.pi * small ** 2, out)
    part = (d < r1 + r2) & ~inside
    with np.errstate(invalid="ignore", divide="ignore"):
        dd = np.where(part, d, 1.0)
        a1 = np.arccos(np.clip((dd ** 2 + r1 ** 2 - r2 ** 2) / (2 * dd * r1), -1.0, 1.0))
        a2 = np.arccos(np.clip((dd ** 2 + r2 ** 2 - r1 ** 2) / (2 * dd * r2), -1.0, 1.0))
        lens = (r1 ** 2 * (a1 - np.sin(2 * a1) / 2) + r2 ** 2 * (a2 - np.sin(2 * a2) / 2))
    return np.where(part, lens, out)
