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


def local_sample_points(world: World, index: int, n_per_axis: int = 3) -> np.ndarray:
    """Sample points ``(P, 3)`` in the frame of object ``index`` (computed from its AABB at identity)."""
    pose0 = world.get_poses([index])
    ident = pose0.copy()
    ident[0, 3:] = [0.0, 0.0, 0.0, 1.0]
    world.set_poses(ident, [index])
    lo, hi = world.aabbs([index])[0]
    world.set_poses(pose0, [index])
    centre_world = 0.5 * (lo + hi)
    centre = centre_world - ident[0, :3]
    half = 0.5 * (hi - lo)
    g = np.linspace(-1.0, 1.0, n_per_axis)
    grid = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    norms = np.linalg.norm(grid, axis=1)
    grid = grid[norms > 0] / norms[norms > 0, None]  # directions, on the unit sphere
    pts = np.vstack([np.zeros((1, 3)), 0.8 * grid])  # centre + points inside the ellipsoid
    return centre + pts * half


def visible_fraction(world: World, camera: Camera, indices, local_points: dict[int, np.ndarray],
                     poses: np.ndarray | None = None) -> np.ndarray:
    """Fraction ``(n,)`` of each object's sample points that the camera sees.

    Args:
        world: the world to cast rays in (its current state).
        camera: the camera.
        indices: object indices (n,).
        local_points: sample points per object index, in the object's frame (see
            :func:`local_sample_points`).
        poses: ``(n, 7)`` current poses of ``indices`` (read from the world if None).
    """
    indices = [int(i) for i in np.atleast_1d(indices)]
    if not indices:
        return np.zeros(0)
    if poses is None:
        poses = world.get_poses(indices)
    pts, owner = [], []
    for k, i in enumerate(indices):
        lp = local_points[i]
        pts.append(poses[k, :3] + quat_rotate(np.broadcast_to(poses[k, 3:], (len(lp), 4)), lp))
        owner.append(np.full(len(lp), k))
    pts = np.vstack(pts)
    owner = np.concatenate(owner)
    in_view = camera.in_view(pts)
    frac = np.zeros(len(indices))
    if np.any(in_view):
        sel = np.flatnonzero(in_view)
        d = pts[sel] - camera.position
        ends = camera.position + d * 1.05  # a little beyond the point, so the object itself is hit
        hit, _ = world.ray_test(np.broadcast_to(camera.position, ends.shape), ends)
        target = np.asarray(indices)[owner[sel]]
        seen = hit == target
        np.add.at(frac, owner[sel], seen.astype(float))
    counts = np.bincount(owner, minlength=len(indices))
    return frac / np.maximum(counts, 1)
