"""Vectorised rigid-body transforms on numpy arrays.

Conventions: positions in metres; quaternions are ``(x, y, z, w)`` (pybullet's and scipy's order);
a pose is a ``(..., 7)`` array ``[px, py, pz, qx, qy, qz, qw]``. All functions broadcast over leading
axes and return new float64 arrays.
"""
from __future__ import annotations

import numpy as np

IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of ``(..., 4)`` quaternions (x, y, z, w): rotate by b, then by a."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]  # (not moveaxis: its axis handling
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]  # dominates for one pose)
    return np.stack([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of unit quaternions ``(..., 4)``."""
    q = np.array(q, dtype=float)
    q[..., :3] *= -1.0
    return q


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of vectors ``(..., 3)`` (broadcast), as ``np.cross`` computes them (the same
    products and differences, so the same bits) without its axis handling, which dominates for the
    small arrays of the hot paths."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` ``(..., 3)`` by unit quaternions ``q`` ``(..., 4)``."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``q (..., 4)`` (x, y, z, w; normalised here):
    ``quat_to_matrix(q) @ v`` is ``quat_rotate(q, v)``."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                     2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                     2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
                    axis=-1).reshape(q.shape[:-1] + (3, 3))


def quat_normalize(q: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit quaternions with a non-negative w. Raises ``ValueError`` on a zero-length quaternion."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < eps):
        raise ValueError("zero-length quaternion")
    q = q / n
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle in radians ``[0, pi]`` between unit quaternions ``a`` and ``b`` ``(..., 4)``."""
    d = np.abs(np.sum(np.asarray(a, float) * np.asarray(b, float), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


def pose_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose product ``a * b`` of ``(..., 7)`` poses: b expressed in a's frame, mapped to the world."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    pos = a[..., :3] + quat_rotate(a[..., 3:], b[..., :3])
    quat = quat_multiply(a[..., 3:], b[..., 3:])
    return np.concatenate([pos, quat], axis=-1)


def pose_inverse(a: np.ndarray) -> np.ndarray:
    """Inverse of ``(..., 7)`` poses."""
    a = np.asarray(a, dtype=float)
    qi = quat_conjugate(a[..., 3:])
    return np.concatenate([-quat_rotate(qi, a[..., :3]), qi], axis=-1)


def carry_pose(child: np.ndarray, parent_before: np.ndarray, parent_after: np.ndarray) -> np.ndarray:
    """Move ``child`` rigidly with a parent that moved from ``parent_before`` to ``parent_after``.

    All ``(..., 7)``. Rotation of the parent is applied to the child, about the parent's origin.
    """
    rel = pose_compose(pose_inverse(parent_before), child)
    return pose_compose(parent_after, rel)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternions from unit ``axis`` ``(..., 3)`` and ``angle`` (radians, ``(...)``)."""
    axis = np.asarray(axis, dtype=float)
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([axis * np.sin(half), np.cos(half)], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, radians) of unit quaternions ``(..., 4)``."""
    q = quat_normalize(q)
    s = np.linalg.norm(q[..., :3], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 3])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)
    return q[..., :3] * scale[..., None]


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions from rotation vectors ``(..., 3)`` (axis * angle, radians)."""
    r = np.asarray(r, dtype=float)
    angle = np.linalg.norm(r, axis=-1)
    half = 0.5 * angle
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-300), 0.5)
    return np.concatenate([r * k[..., None], np.cos(half)[..., None]], axis=-1)


def link_from_com(com_poses: np.ndarray, com_vel: np.ndarray | None, inertial: np.ndarray,
                  inertial_inv: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Centre-of-mass poses ``(..., n, 7)`` and velocities ``(..., n, 6)`` (or None) of bodies whose
    centre-of-mass frame in their link frame is ``inertial (n, 7)`` (``inertial_inv`` its inverse)
    to link-frame poses and link-origin velocities (linear m/s, angular rad/s, world frame)."""
    poses = pose_compose(com_poses, inertial_inv)
    if com_vel is None:
        return poses, None
    vel = np.array(com_vel, dtype=float)
    vel[..., :3] += np.cross(vel[..., 3:], -quat_rotate(poses[..., 3:], inertial[:, :3]))
    return poses, vel


def com_from_link(poses: np.ndarray, vel: np.ndarray | None,
                  inertial: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The inverse of :func:`link_from_com`: link-frame poses ``(..., n, 7)`` and link-origin
    velocities ``(..., n, 6)`` (or None) to centre-of-mass ones."""
    com = pose_compose(poses, inertial)
    if vel is None:
        return com, None
    cvel = np.array(vel, dtype=float)
    cvel[..., :3] += np.cross(cvel[..., 3:], quat_rotate(poses[..., 3:], inertial[:, :3]))
    return com, cvel
