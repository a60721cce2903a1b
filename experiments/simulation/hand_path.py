"""The scripted hand's path: smooth segments between waypoints (position by smoothstep, orientation
by spherical interpolation)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def _quat_from_rpy(rpy_deg) -> np.ndarray:
    """Quaternion (x, y, z, w) of roll, pitch, yaw in degrees (fixed axes x, y, z)."""
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_quat()


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    d = float(np.dot(a, b))
    if d < 0.0:
        b, d = -b, -d
    if d > 0.9995:
        q = a + s * (b - a)
        return q / np.linalg.norm(q)
    theta = math.acos(min(1.0, d))
    return (math.sin((1 - s) * theta) * a + math.sin(s * theta) * b) / math.sin(theta)


def _smooth(s: float) -> float:
    """Smoothstep: position profile with zero velocity at both ends of a motion."""
    s = min(1.0, max(0.0, s))
    return s * s * (3.0 - 2.0 * s)


@dataclass
class _Segment:
    t0: float
    t1: float
    p0: np.ndarray
    p1: np.ndarray
    q0: np.ndarray
    q1: np.ndarray

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = 1.0 if self.t1 <= self.t0 else _smooth((t - self.t0) / (self.t1 - self.t0))
        return self.p0 + (self.p1 - self.p0) * s, _slerp(self.q0, self.q1, s)
