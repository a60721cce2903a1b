"""Synthetic camera: which objects of a pybullet world a pinhole camera can see.

Visibility is decided geometrically, by batched ray tests in the world that holds the true scene
(including bodies that are not scene objects, such as the scripted hand and the human torso, which
occlude like anything else):

* each object carries ``n`` sample points, fixed in its link frame and drawn once, deterministically
  (a generator seeded from the object id): inside the volume of boxes, spheres and cylinders, inside
  the five walls of containers, and inside the local bounding box of URDF bodies;
* every frame, a ray is cast from the camera centre through each sample point and on past it (by the
  object's bounding-box diagonal). A point *sees the object* when the first body the ray hits is the
  object itself, and it is *occluded* when another body (scene object, floor, hand, torso) is hit
  before the point. Rays that miss the object and hit nothing in front of the point (possible for
  points of a URDF bounding box that lie outside the mesh) are ignored;
* the visible fraction of an object is (points that see the object and lie inside the view frustum)
  / (points that see the object or are occluded). A point outside the frustum (beyond the field of
  view, nearer than ``near`` or farther than ``far``) never counts as seen.

An object is perceivable when its visible fraction is at least the threshold (0.3 by default). The
camera looks from ``CameraSpec.position`` at ``CameraSpec.target``; ``fov_deg`` is the vertical field
of view and ``aspect`` the width / height ratio.
"""
from __future__ import annotations

import copy
import math
import zlib

import numpy as np

from physics.scene import CameraSpec, ObjectSpec
from physics.transforms import pose_compose, pose_inverse
from physics.visibility import Camera
from physics.world import World

DEFAULT_POINTS = 64


def _object_rng(object_id: str) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32(object_id.encode("utf-8")))


def sample_points(spec: ObjectSpec, n: int, local_aabb: np.ndarray | None = None) -> np.ndarray:
    """``n`` points (n, 3) in the link frame of ``spec``, inside its collision geometry.

    Primitive frames are at their centres; points keep 10 % clear of the surface so that a ray through
    them always enters the object before reaching them. ``local_aabb`` (2, 3) is required for URDFs.
    """
    rng = _object_rng(spec.id)
    if spec.shape == "box":
        half = 0.45 * np.asarray(spec.size)
        return rng.uniform(-1.0, 1.0, (n, 3)) * half
    if spec.shape == "sphere":
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = 0.9 * spec.radius * rng.random(n) ** (1.0 / 3.0)
        return d * r[:, None]
    if spec.shape == "cylinder":
        ang = rng.uniform(0.0, 2.0 * math.pi, n)
        r = 0.9 * spec.radius * np.sqrt(rng.random(n))
        z = rng.uniform(-0.45, 0.45, n) * spec.height
        return np.stack([r * np.cos(ang), r * np.sin(ang), z], axis=1)
    if spec.shape == "container":
        sx, sy, sz = spec.size
        w = spec.wall
        # slabs (centre, half extents) of the floor and the four walls, as in physics.world
        slabs = [((0, 0, -sz / 2 + w / 2), (sx / 2, sy / 2, w / 2)),
                 ((sx / 2 - w / 2, 0, 0), (w / 2, sy / 2, sz / 2)),
                 ((-sx / 2 + w / 2, 0, 0), (w / 2, sy / 2, sz / 2)),
                 ((0, sy / 2 - w / 2, 0), (sx / 2 - w, w / 2, sz / 2)),
                 ((0, -sy / 2 + w / 2, 0), (sx / 2 - w, w / 2, sz / 2))]
        centres = np.array([s[0] for s in slabs], dtype=float)
        halves = np.array([s[1] for s in slabs], dtype=float)
        # walls chosen in proportion to their visible area (largest two extents of each slab)
        areas = np.array([np.prod(np.sort(h)[1:]) for h in halves])
        which = rng.choice(len(slabs), size=n, p=areas / areas.sum())
        return centres[which] + rng.uniform(-0.8, 0.8, (n, 3)) * halves[which]
    if local_aabb is None:
        raise ValueError(f"object {spec.id!r}: a URDF needs its local bounding box")
    lo, hi = np.asarray(local_aabb, dtype=float)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return mid + rng.uniform(-0.9, 0.9, (n, 3)) * half


def local_aabb(world: World, index: int) -> np.ndarray:
    """Bounding box (2, 3) of object ``index`` in its link frame, from its current world AABB
    (exact for an object whose current orientation is axis-aligned, conservative otherwise)."""
    box = world.aabbs([index])[0]
    corners = np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    pose = world.get_poses([index])[0]
    inv = pose_inverse(pose)
    local = pose_compose(np.broadcast_to(inv, (8, 7)),
                         np.concatenate([corners, np.tile([0, 0, 0, 1.0], (8, 1))], axis=1))[:, :3]
    return np.stack([local.min(axis=0), local.max(axis=0)])


class SyntheticCamera:
    """A pinhole camera over ``world`` (the ground-truth world).

    ``points_per_object`` sample points per object are fixed at construction (URDF bounding boxes
    are read from the world at that moment). :meth:`visible_fractions` returns (M,) fractions in [0, 1]
    and :meth:`visible` the (M,) bool ``fraction >= threshold``.
    """

    def __init__(self, world: World, camera: CameraSpec, *, points_per_object: int = DEFAULT_POINTS,
                 threshold: float = 0.3):
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {threshold}")
        self.world = world
        self.camera = camera
        self.threshold = float(threshold)
        self.n = int(points_per_object)
        pts = []
        for i, spec in enumerate(world.scene.objects):
            box = local_aabb(world, i) if spec.shape == "urdf" else None
            pts.append(sample_points(spec, self.n, box))
        self.points = np.stack(pts)  # (M, n, 3) link frame
        radius = np.linalg.norm(self.points, axis=2).max(axis=1)
        self._extension = np.repeat(np.maximum(2.0 * radius, 0.02), self.n)  # (M*n,)
        self._owner = np.repeat(np.arange(len(pts)), self.n)
        self._pinhole = Camera(camera)  # the frustum test is the estimator's own
        self.origin = self._pinhole.position

    def moved_to(self, camera: CameraSpec) -> "SyntheticCamera":
        """The same camera (world, sample points, threshold) looking from ``camera`` instead."""
        out = copy.copy(self)
        out.camera = camera
        out._pinhole = Camera(camera)
        out.origin = out._pinhole.position
        return out

    def world_points(self, poses: np.ndarray | None = None) -> np.ndarray:
        """Sample points in the world frame (M, n, 3) at ``poses`` (M, 7) (default: current poses)."""
        if poses is None:
            poses = self.world.get_poses()
        m = len(poses)
        pose_rows = np.repeat(np.asarray(poses, dtype=float), self.n, axis=0)
        local = np.concatenate([self.points.reshape(-1, 3), np.tile([0, 0, 0, 1.0], (m * self.n, 1))], axis=1)
        return pose_compose(pose_rows, local)[:, :3].reshape(m, self.n, 3)

    def in_frustum(self, points: np.ndarray) -> np.ndarray:
        """Bool mask (...,) of world points (..., 3) inside the view frustum."""
        return self._pinhole.in_view(points)

    def visible_fractions(self, poses: np.ndarray | None = None) -> np.ndarray:
        """Visible fraction (M,) of every object in the world's current state.

        ``poses`` (M, 7) may pass the current poses if the caller already has them (they must be the
        world's current poses: the rays are cast in the world as it is).
        """
        pts = self.world_points(poses).reshape(-1, 3)
        d = pts - self.origin
        dist = np.linalg.norm(d, axis=1)
        dist = np.maximum(dist, 1e-9)
        total = dist + self._extension
        ends = self.origin + d * (total / dist)[:, None]
        hit, frac = self.world.ray_test(np.broadcast_to(self.origin, pts.shape), ends)
        point_frac = dist / total
        sees = hit == self._owner
        something = (hit != -1) | (frac < 1.0)  # -1 with frac < 1: a body outside the scene (hand)
        occluded = ~sees & something & (frac < point_frac)
        seen = sees & self.in_frustum(pts)
        m = len(self.points)
        num = seen.reshape(m, self.n).sum(axis=1)
        den = (sees | occluded).reshape(m, self.n).sum(axis=1)
        return np.where(den > 0, num / np.maximum(den, 1), 0.0)

    def visible(self, poses: np.ndarray | None = None) -> np.ndarray:
        """(M,) bool: objects whose visible fraction reaches the threshold."""
        return self.visible_fractions(poses) >= self.threshold
