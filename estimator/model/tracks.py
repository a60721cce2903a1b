"""Pure functions over one object's recent detections, oldest first, each ``(t, position, orientation)``
(s; ``(3,)`` m; ``(4,)`` quaternion x, y, z, w or None): the least-squares line through them, the free
fall through the last two, and whether they rested. The perception memory
(:class:`~estimator.model.perception_memory.PerceptionMemory`) keeps the detections and calls these.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["dwell_back", "fit_line", "free_fall", "rested"]


def fit_line(history, since: float, t: float) -> tuple[np.ndarray, float, np.ndarray, float, int]:
    """Least-squares line through the detections of ``history`` from ``since`` (s) on, the latest at
    ``t`` (s): the slope ``(3,)`` (m/s), the spread of the detection times about their mean ``sxx``
    (s^2), the line's horizontal position at ``t`` ``(2,)`` (m), the detections' horizontal scatter
    about it (m, RMS per axis over ``2 (n - 2)`` degrees of freedom; NaN under three detections) and
    those degrees of freedom. For fewer than two detections, or all at one time, ``(0, 0, the latest
    detection, NaN, 0)``."""
    pts = [(h[0], h[1]) for h in history if h[0] >= since]
    latest = np.asarray(history[-1][1][:2], dtype=float)
    if len(pts) < 2:
        return np.zeros(3), 0.0, latest, math.nan, 0
    ts = np.array([p[0] for p in pts])
    xs = np.array([p[1] for p in pts])
    t_mean, x_mean = ts.mean(), xs.mean(axis=0)
    dt = ts - t_mean
    sxx = float(dt @ dt)
    if sxx <= 1e-12:
        return np.zeros(3), 0.0, latest, math.nan, 0
    slope = dt @ (xs - x_mean) / sxx
    resid = xs[:, :2] - x_mean[:2] - dt[:, None] * slope[None, :2]
    dof = 2 * (len(pts) - 2)
    scatter = math.sqrt(float(np.sum(resid ** 2)) / dof) if dof > 0 else math.nan
    return slope, sxx, x_mean[:2] + slope[:2] * (t - t_mean), scatter, max(dof, 0)


def fit_acceleration(history, since: float, t: float, sigma: float,
                     min_points: int = 5, min_span: float = 0.15) -> tuple[np.ndarray, float, float] | None:
    """Constant horizontal acceleration through the detections of ``history`` from ``since`` (s) to
    ``t`` (s): the least-squares parabola ``p0 + v tau + a tau^2 / 2`` per axis. Returns ``(a (2,)
    m/s^2, its standard error per axis m/s^2, the detections' time span s)`` for detection noise
    ``sigma`` (m per axis); None with fewer than ``min_points`` detections or a span under
    ``min_span`` (s). Over a span T with n detections the standard error falls as ``sigma /
    (sqrt(n) T^2)``: a roll seen for a second tells its deceleration far better than the velocity
    of one reasoning step does."""
    pts = [(h[0], h[1]) for h in history if since - 1e-9 <= h[0] <= t + 1e-9]
    if len(pts) < min_points:
        return None
    ts = np.array([p[0] for p in pts])
    span = float(ts[-1] - ts[0])
    if span < min_span - 1e-9:
        return None
    tau = ts - ts.mean()
    X = np.stack([np.ones_like(tau), tau, 0.5 * tau * tau], axis=1)
    xs = np.array([p[1][:2] for p in pts], dtype=float)
    try:
        inv = np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return None
    return (inv @ (X.T @ xs))[2], float(sigma) * math.sqrt(max(float(inv[2, 2]), 0.0)), span


def free_fall(history, segment_start: float, times: np.ndarray, g: float,
              sigma: float) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The free fall through the last two detections of ``history`` (both at or after
    ``segment_start``, s) under gravity ``g`` (m/s^2, positive down), at ``times (T,)`` (s): heights
    ``(T,)`` (m), vertical velocities ``(T,)`` (m/s) and that velocity's standard error (m/s:
    ``sqrt(2) sigma`` over their interval, ``sigma`` the detection noise in m). Their difference is
    the velocity half-way between them; the velocity at the last one, ``v``, adds gravity over half
    their interval. At a time the fall descends: that height and velocity; carried back to a time
    before it began: at rest at the fall's top, ``z + v^2 / 2 g``. None with fewer than two
    detections in the segment, or not moving down at the last one."""
    if len(history) < 2 or history[-2][0] < segment_start - 1e-9:
        return None
    (t1, p1, _), (t2, p2, _) = history[-2], history[-1]
    if not t2 > t1:
        return None
    v = (p2[2] - p1[2]) / (t2 - t1) - 0.5 * g * (t2 - t1)
    if v >= 0.0:
        return None
    tau = times - t2
    at = v - g * tau
    descending = at < 0.0
    z = np.where(descending, p2[2] + v * tau - 0.5 * g * tau * tau, p2[2] + v * v / (2.0 * g))
    return z, np.where(descending, at, 0.0), math.sqrt(2.0) * sigma / (t2 - t1)


def dwell_back(history, t: float, dwell: float) -> tuple | None:
    """The latest detection of ``history`` at least ``dwell`` (s) before ``t`` (s); None when there is
    none."""
    horizon = t - dwell + 1e-9
    return next((h for h in reversed(history) if h[0] <= horizon), None)


def rested(history, t: float, dwell: float, speed: float, spin: float, distance: float | None = None) -> bool:
    """Whether the detections of ``history`` say the object rested at ``t`` (s): its latest detection
    within ``dwell`` (s) of ``t``, and from the latest one ``dwell`` before it (detections that
    stopped coming, the object out of view, say how it moved while seen, not that it came to rest
    since) it moved less than ``speed * span`` (m/s times s; and, given, ``distance`` m) and turned
    less than ``spin * span`` (rad/s times s), ``span`` their interval, at least ``dwell``."""
    if not history or t - history[-1][0] > dwell:
        return False
    old = dwell_back(history, history[-1][0], dwell)
    if old is None:
        return False
    t0, p0, q0 = old
    t1, p1, q1 = history[-1]
    span = max(t1 - t0, dwell)
    moved = math.dist(p0, p1) < min(speed * span, math.inf if distance is None else distance)
    turned = True
    if q0 is not None and q1 is not None:
        dot = min(1.0, abs(sum(a * b for a, b in zip(q0, q1))))
        turned = 2.0 * math.acos(dot) < spin * span
    return moved and turned
