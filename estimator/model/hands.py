"""Tracked hands: each hand's position filtered over its frames, and a held object's offset to its
hand averaged over the frames that show both.

A skeleton tracker's hand is about a centimetre off in every frame (``HandConfig.measurement_std``),
and a held object that its hand carries out of view is put at the hand plus its offset to it
(:meth:`~estimator.model.perception_memory.PerceptionMemory.hand_target`). Read from one frame each, the
hand's noise enters twice, once in the offset and once in the hand now; the errors of the object
that result are what the particles' spread then has to cover (``NoiseConfig.held_offset_std``).
Here the hand is a constant-velocity Kalman filter (the pose tracker's model,
:func:`transition` and :func:`process_noise`, which the pose tracker :mod:`estimator.applications.tracker` uses too), and the offset
an exponential average of (detection - raw hand), whose noise averages out because the raw hand's
errors are independent from frame to frame.

Positions in metres, times in seconds. Configuration: :class:`~estimator.config.HandConfig`.
"""
from __future__ import annotations

import math

import numpy as np

from ..config import HandConfig


def transition(dt: float) -> np.ndarray:
    """Constant-velocity transition ``F (6, 6)`` over ``dt`` seconds."""
    f = np.eye(6)
    f[:3, 3:] = dt * np.eye(3)
    return f


def process_noise(dt: float, accel_std: float) -> np.ndarray:
    """White-acceleration process noise ``Q (6, 6)`` over ``dt`` s, ordered ``[x, y, z, vx, vy, vz]``:
    an acceleration of standard deviation ``accel_std`` (m/s^2) held over each step, per axis ``[[dt^4 /
    4, dt^3 / 2], [dt^3 / 2, dt^2]] accel_std^2`` (filterpy's ``Q_discrete_white_noise(2, dt, var,
    block_size=3, order_by_dim=False)``, value for value; written here so that the estimator does not
    import filterpy, whose import pulls in most of scipy)."""
    per_axis = np.array([[.25 * dt ** 4, .5 * dt ** 3], [.5 * dt ** 3, dt ** 2]])
    return np.kron(per_axis, np.eye(3)) * accel_std ** 2


class HandFilter:
    """One tracked hand's position and velocity, filtered: state ``x (6,)`` = ``[x, y, z, vx, vy,
    vz]`` (m, m/s), covariance ``P (6, 6)``. A new filter, or one whose hand has not been seen for
    ``restart_gap``, starts at the next position at rest (velocity standard deviation 1 m/s).
    With ``config.filtered`` False nothing is filtered: :attr:`position` is the latest raw position
    (and :attr:`velocity` NaN)."""

    def __init__(self, config: HandConfig):
        self.config = config
        self.t = -math.inf
        self.x = np.full(6, np.nan)
        self.P = np.eye(6)
        self.raw = np.full(3, np.nan)

    def update(self, t: float, z) -> np.ndarray:
        """Take the hand's position ``z (3,)`` at time ``t`` (not before the last); returns the
        filtered position ``(3,)``."""
        z = np.asarray(z, dtype=float).reshape(3)
        cfg = self.config
        dt = t - self.t
        if cfg.filtered and not dt <= cfg.restart_gap:  # first position, or back after a gap
            self.x = np.concatenate([z, np.zeros(3)])
            self.P = np.diag([cfg.measurement_std ** 2] * 3 + [1.0] * 3)
        elif cfg.filtered and dt > 0:
            f = transition(dt)
            x = f @ self.x
            p = f @ self.P @ f.T + process_noise(dt, cfg.accel_std)
            s = p[:3, :3] + cfg.measurement_std ** 2 * np.eye(3)
            gain = np.linalg.solve(s, p[:3, :]).T  # P H^T S^-1 (S and P symmetric)
            self.x = x + gain @ (z - x[:3])
            self.P = p - gain @ p[:3, :]  # (I - K H) P, H selecting the position rows
            self.P = 0.5 * (self.P + self.P.T)
        self.t, self.raw = t, z
        return self.position

    @property
    def position(self) -> np.ndarray:
        """Filtered position ``(3,)`` m (the raw one when not filtered); NaN before any frame."""
        return (self.x[:3] if self.config.filtered else self.raw).copy()

    @property
    def velocity(self) -> np.ndarray:
        """Filtered velocity ``(3,)`` m/s; NaN before any frame."""
        return self.x[3:].copy()


def average_offset(mean: np.ndarray, n: int, dt: float, difference: np.ndarray,
                   config: HandConfig) -> tuple[np.ndarray, int]:
    """The offset of a held object to its hand after one more frame that shows both.

    ``mean (3,)`` m: the average so far over ``n`` frames (``n = 0``: none); ``dt`` (s) since the
    last of them; ``difference (3,)``: this frame's detection minus the raw hand. The new frame
    weighs ``max(1 / (n + 1), 1 - exp(-dt / offset_time))``; a difference farther than
    ``offset_gate`` from the mean, or ``config.filtered`` False, starts again at it. Returns the new
    mean ``(3,)`` and count."""
    difference = np.asarray(difference, dtype=float)
    if n <= 0 or not config.filtered or np.linalg.norm(difference - mean) > config.offset_gate:
        return difference.copy(), 1
    a = max(1.0 / (n + 1), 1.0 - math.exp(-max(dt, 0.0) / config.offset_time))
    return mean + a * (difference - mean), n + 1


def filtered_track(times, positions, config: HandConfig) -> np.ndarray:
    """Filtered positions ``(N, 3)`` of one hand over a stream: ``times (N,)`` s, ``positions
    (N, 3)`` m with NaN rows where the hand was not tracked (NaN out there too)."""
    hand = HandFilter(config)
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    out = np.full(pos.shape, np.nan)
    for i, (t, z) in enumerate(zip(times, pos)):
        if np.all(np.isfinite(z)):
            out[i] = hand.update(float(t), z)
    return out
