"""Perception faults of a synthetic 6D pose tracker.

The synthetic camera (:mod:`experiments.simulation.camera`) decides *whether* an object can be seen; this module
decides *what the tracker reports* about a seen object. Every fault is configurable in a
:class:`PerceptionConfig` and every random draw comes from the ``numpy.random.Generator`` handed to
:class:`PerceptionModel` (never from numpy's global state), so a seed fixes the whole stream.

Faults, applied in this order to the true link-frame pose of a visible, non-static object:

* **dropout**: with probability ``dropout_prob`` per object and frame, the object is missing;
* **position noise**: independent Gaussian noise of standard deviation ``position_std`` (m) per axis;
* **height offset** ("floating"): a constant offset (m) added to z, drawn once per object, uniformly in
  ``height_offset = (lo, hi)`` (``lo == hi`` gives the same offset for every object);
* **interpenetration**: with probability ``interpenetration_prob`` per object and frame the reported
  z is lowered by ``interpenetration_depth`` (m), i.e. the object sinks into its support;
* **orientation noise**: the true orientation is composed (in the object frame) with a rotation whose
  rotation vector is Gaussian with ``orientation_std_deg`` degrees per axis;
* **fixed orientation**: objects listed in ``fixed_orientation`` (colour-segmented blobs) report the
  identity quaternion instead.

Timing: frames come at ``rate_hz``; with ``latency_s`` > 0 the frame stamped ``t`` reports the scene as
it was at ``t - latency_s`` (the simulator quantises the latency to physics steps).

Hands (``hands_tracked``): the hand position is reported in every frame with Gaussian noise
``hand_std`` (m) per axis, whatever the camera sees (a skeleton tracker, not the object tracker).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from physics.transforms import quat_from_rotvec, quat_multiply, quat_normalize


@dataclass(frozen=True)
class PerceptionConfig:
    """Configuration of the synthetic tracker. Units: metres, degrees, seconds, Hz.

    Defaults are a fault-free 30 Hz tracker that sees an object when at least 30 % of it is visible.
    """

    rate_hz: float = 30.0
    latency_s: float = 0.0
    visibility_threshold: float = 0.3
    """An object is perceivable when its visible fraction (see :mod:`experiments.simulation.camera`) is >= this."""
    points_per_object: int = 64
    """Sample points per object used by the camera's ray tests."""
    position_std: float = 0.0
    orientation_std_deg: float = 0.0
    height_offset: tuple[float, float] = (0.0, 0.0)
    interpenetration_prob: float = 0.0
    interpenetration_depth: float = 0.015
    dropout_prob: float = 0.0
    fixed_orientation: tuple[str, ...] = ()
    """Object ids that report the identity orientation; ``("*",)`` means every object."""
    report_static: bool = False
    """Whether static objects (the table) appear in the observations."""
    hands_tracked: bool = False
    hand_std: float = 0.0

    def __post_init__(self):
        def check(name, ok):
            value = getattr(self, name)
            if isinstance(value, bool) or not ok(value):
                raise ValueError(f"perception.{name}: invalid value {value!r}")

        finite = lambda v: isinstance(v, (int, float)) and math.isfinite(v)  # noqa: E731
        check("rate_hz", lambda v: finite(v) and 0 < v <= 240)
        check("latency_s", lambda v: finite(v) and 0 <= v <= 5)
        check("visibility_threshold", lambda v: finite(v) and 0 < v <= 1)
        check("points_per_object", lambda v: isinstance(v, int) and 8 <= v <= 4096)
        for name in ("position_std", "orientation_std_deg", "interpenetration_depth", "hand_std"):
            check(name, lambda v: finite(v) and v >= 0)
        for name in ("interpenetration_prob", "dropout_prob"):
            check(name, lambda v: finite(v) and 0 <= v <= 1)
        lo_hi = self.height_offset
        if (not isinstance(lo_hi, tuple) or len(lo_hi) != 2 or not all(finite(v) for v in lo_hi)
                or lo_hi[0] > lo_hi[1]):
            raise ValueError(f"perception.height_offset: expected (lo, hi) with lo <= hi, got {lo_hi!r}")
        if not isinstance(self.fixed_orientation, tuple) or not all(
                isinstance(v, str) for v in self.fixed_orientation):
            raise ValueError("perception.fixed_orientation: expected a tuple of object ids")

    def to_dict(self) -> dict:
        """The configuration as plain JSON values (fixed key order)."""
        return {"rate_hz": self.rate_hz, "latency_s": self.latency_s,
                "visibility_threshold": self.visibility_threshold,
                "points_per_object": self.points_per_object, "position_std": self.position_std,
                "orientation_std_deg": self.orientation_std_deg,
                "height_offset": list(self.height_offset),
                "interpenetration_prob": self.interpenetration_prob,
                "interpenetration_depth": self.interpenetration_depth,
                "dropout_prob": self.dropout_prob, "fixed_orientation": list(self.fixed_orientation),
                "report_static": self.report_static, "hands_tracked": self.hands_tracked,
                "hand_std": self.hand_std}


@dataclass
class Observation:
    """What the tracker reports in one frame: ``reported`` (M,) bool, ``poses`` (M, 7) link-frame
    poses (rows of unreported objects are NaN), and the tracked hand position (3,) or ``None``."""

    reported: np.ndarray
    poses: np.ndarray
    hand: np.ndarray | None = None
    dropped: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """(M,) bool: visible objects removed by a dropout."""


class PerceptionModel:
    """Applies the faults of ``config`` to true poses, drawing from ``rng``.

    ``object_ids`` and ``static`` (M,) bool describe the scene. The per-object height offsets are drawn
    once, here, in scene order (:attr:`height_offsets`, metres).
    """

    def __init__(self, config: PerceptionConfig, object_ids, static, rng: np.random.Generator):
        self.config = config
        self.object_ids = tuple(object_ids)
        self.static = np.asarray(static, dtype=bool)
        self.rng = rng
        m = len(self.object_ids)
        if self.static.shape != (m,):
            raise ValueError(f"static must have shape ({m},), got {self.static.shape}")
        lo, hi = config.height_offset
        self.height_offsets = lo + (hi - lo) * rng.random(m) if hi > lo else np.full(m, float(lo))
        if "*" in config.fixed_orientation:
            self.fixed = np.ones(m, dtype=bool)
        else:
            self.fixed = np.array([oid in config.fixed_orientation for oid in self.object_ids], dtype=bool)

    def observe(self, true_poses: np.ndarray, visible: np.ndarray,
                hand_position: np.ndarray | None = None) -> Observation:
        """One frame. ``true_poses`` (M, 7), ``visible`` (M,) bool from the camera, optional true hand
        position (3,). The same number of random draws is made whatever is visible, so a change of
        visibility in one frame does not shift the noise of later frames."""
        cfg = self.config
        rng = self.rng
        poses = np.asarray(true_poses, dtype=float)
        m = len(poses)
        visible = np.asarray(visible, dtype=bool)
        u_drop = rng.random(m)
        pos_noise = rng.normal(0.0, 1.0, (m, 3)) * cfg.position_std
        u_pen = rng.random(m)
        rot_noise = rng.normal(0.0, 1.0, (m, 3)) * math.radians(cfg.orientation_std_deg)
        hand_noise = rng.normal(0.0, 1.0, 3) * cfg.hand_std
        candidate = visible & (cfg.report_static | ~self.static)
        dropped = candidate & (u_drop < cfg.dropout_prob)
        reported = candidate & ~dropped
        out = np.full((m, 7), np.nan)
        pos = poses[:, :3] + pos_noise
        pos[:, 2] += self.height_offsets
        pos[:, 2] -= np.where(u_pen < cfg.interpenetration_prob, cfg.interpenetration_depth, 0.0)
        quat = quat_normalize(quat_multiply(poses[:, 3:], quat_from_rotvec(rot_noise)))
        quat[self.fixed] = (0.0, 0.0, 0.0, 1.0)
        out[reported, :3] = pos[reported]
        out[reported, 3:] = quat[reported]
        hand = None
        if cfg.hands_tracked and hand_position is not None:
            hand = np.asarray(hand_position, dtype=float) + hand_noise
        return Observation(reported=reported, poses=out, hand=hand, dropped=dropped)
