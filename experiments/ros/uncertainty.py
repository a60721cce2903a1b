"""What the ROS node publishes about an object's uncertainty, in plain numpy (no ROS needed):
the 6 x 6 pose covariance of ``geometry_msgs/PoseWithCovariance`` and the 90 % region's ellipsoid.

**Pose covariance.** ROS orders it (x, y, z, rotation about X, rotation about Y, rotation about Z),
row-major, the rotations about the *fixed* axes of the header's frame (the world frame here):
a particle's rotation part is the rotation vector of ``q_k * q_mean^-1`` (rad), ``q_mean`` the
belief's orientation. The position block is the belief's headline ``position_cov`` (the most
probable hypothesis's covariance, floor included, m^2), the rotation block the weighted covariance
of the particles' rotation vectors (rad^2). The position-rotation block is the particles'
cross-covariance carried over to the reported position block: with the particles' joint
covariance ``S = [[Spp, Spr], [Srp, Srr]]`` and the reported ``P``, ``A = P^1/2 Spp^-1/2`` and the
result is ``diag(A, I) S diag(A, I)^T``, which is symmetric positive semi-definite whenever ``S``
is and whose position block is exactly ``P`` (with a degenerate ``Spp`` the cross block is zero).
"""
from __future__ import annotations

import numpy as np

from physics.transforms import quat_conjugate, quat_multiply, quat_to_rotvec


def _sqrtm_psd(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(eigenvectors, eigenvalues clipped at 0) of the symmetric part of a PSD matrix."""
    vals, vecs = np.linalg.eigh(0.5 * (m + m.T))
    vals = np.clip(vals, 0.0, None)
    return vecs, vals


def pose_covariance(position_cov: np.ndarray, orientation: np.ndarray, particles: np.ndarray | None = None,
                    weights: np.ndarray | None = None) -> np.ndarray:
    """The ``(6, 6)`` covariance (see the module docstring) from the reported ``position_cov (3, 3)``
    (m^2), the reported ``orientation (4,)`` (x, y, z, w) and the object's particle poses
    ``particles (K, 7)`` with normalised ``weights (K,)`` (None: no particles, rotation block zero)."""
    out = np.zeros((6, 6))
    p_cov = 0.5 * (np.asarray(position_cov, float) + np.asarray(position_cov, float).T)
    out[:3, :3] = p_cov
    if particles is None or weights is None or len(particles) < 2:
        return out
    w = np.asarray(weights, float)
    w = w / w.sum()
    pos = particles[:, :3]
    q_mean = np.asarray(orientation, float)
    rot = quat_to_rotvec(quat_multiply(particles[:, 3:], quat_conjugate(q_mean)[None]))
    x = np.concatenate([pos - w @ pos, rot - w @ rot], axis=1)  # (K, 6) deviations
    s = (x.T * w) @ x
    out[3:, 3:] = s[3:, 3:]
    vecs_s, vals_s = _sqrtm_psd(s[:3, :3])
    tol = 1e-12 * max(1.0, float(vals_s.max(initial=0.0)))
    if vals_s.min() > tol:
        vecs_p, vals_p = _sqrtm_psd(p_cov)
        p_half = (vecs_p * np.sqrt(vals_p)) @ vecs_p.T
        s_inv_half = (vecs_s / np.sqrt(vals_s)) @ vecs_s.T
        a = p_half @ s_inv_half
        out[:3, 3:] = a @ s[:3, 3:]
        out[3:, :3] = out[:3, 3:].T
    return 0.5 * (out + out.T)


def region_ellipsoid(position_cov: np.ndarray, r2: float, min_size: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """The ellipsoid ``x^T position_cov^-1 x <= r2`` as an RViz sphere marker: (orientation (4,)
    x, y, z, w of its principal axes, scale (3,): full lengths of the axes in m, at least
    ``min_size``)."""
    vals, vecs = np.linalg.eigh(0.5 * (np.asarray(position_cov, float) + np.asarray(position_cov, float).T))
    vals = np.clip(vals, 0.0, None)
    if np.linalg.det(vecs) < 0:
        vecs[:, 0] = -vecs[:, 0]  # a rotation, not a reflection
    scale = np.maximum(2.0 * np.sqrt(r2 * vals), min_size)
    return _quat_from_matrix(vecs), scale


def _quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(r).as_quat()
    return -q if q[3] < 0 else q
