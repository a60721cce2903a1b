"""A per-object Kalman pose tracker that the physics belief keeps alive through occlusion.

A robot's pose tracker is usually one Kalman filter per object. It loses its motion model as soon as an
object is occluded, and on re-appearance it either rejects the detection (outside its gate) or
re-initialises. The particle estimator knows where a hidden object went (it fell, rolled, rides in a
moving bin): :meth:`PhysicsAwareTracker.feedback` turns the estimator's consensus position and
covariance of every object the tracker does not see into a pseudo-measurement, so the track follows
physics with a covariance that grows with the estimator's. The tracker's filtered poses can in turn be
fed to the estimator (:meth:`PhysicsAwareTracker.to_frame` gives a :class:`~estimator.observations.Frame`
with ``position_std`` per object).

Model (per object, filterpy's :class:`~filterpy.kalman.KalmanFilter` does the filtering): state
``x (6,)`` = ``[x, y, z, vx, vy, vz]`` (m, m/s), constant velocity, ``F = [[I, dt I], [0, I]]``; process
noise ``Q`` = filterpy's ``Q_discrete_white_noise(dim=2, dt, var=accel_std**2, block_size=3,
order_by_dim=False)`` (piecewise-constant white acceleration); measurement ``z (3,)`` = position,
``H = [I 0]``, ``R = position_std**2 I`` from the detection's ``position_std`` or
:attr:`TrackerConfig.measurement_std`. A new track starts at the detection with zero velocity,
``P = diag(R, velocity_std**2 I)``.

Only positions are filtered. Orientations are passed through from an object's last detection (or,
while it is unseen and feedback is on, from the belief's consensus orientation): an
orientation filter would need a quaternion-aware (error-state) filter, and the estimator uses
orientations only in its detection likelihood, never in its motion model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..belief import Belief, chi2_quantile, region_radius_sq
from ..model.hands import process_noise, transition
from ..observations import Detection, Frame

if TYPE_CHECKING:  # filterpy's import pulls in most of scipy (a second): imported where a filter is made
    from filterpy.kalman import KalmanFilter

H_POS = np.hstack([np.eye(3), np.zeros((3, 3))])
"""Measurement matrix ``(3, 6)``: a detection measures the position block of the state."""


@dataclass(frozen=True)
class TrackerConfig:
    """Configuration of :class:`PhysicsAwareTracker` (units: m, s).

    Attributes:
        accel_std: standard deviation of the white acceleration of the constant-velocity model
            (m/s^2); ``Q`` uses its square. Fitted (``scene-estimator fit-priors``: 5.0, the 99th
            percentile of the per-axis accelerations of objects held in truth, a robust maximum; their
            RMS is 1.4): of the order of the largest acceleration the filter must follow, not the
            RMS, so that it trails a carry's start and stop by little. At 2 m/s^2 the filtered cup
            lagged its hand where a carry turned, and the estimator fed the filtered stream took
            that lag into the hand offset it carried out of view.
        measurement_std: position noise of a detection without its own ``position_std`` (m).
        velocity_std: initial velocity standard deviation of a new track (m/s).
        gate_probability: a detection is accepted when its Mahalanobis distance squared to the
            predicted position is below the chi-square quantile of this probability with 3 degrees of
            freedom (0.99: 11.34).
        coast_time: a track that has had neither a detection nor a pseudo-measurement for longer than
            this (s) is dropped; until then it is the constant-velocity prediction.
        reinit_after: a detection outside the gate re-initialises the track when the object has had
            no accepted detection for longer than this (s); otherwise it is rejected (counted).
        use_feedback: apply the estimator's pseudo-measurements in :meth:`PhysicsAwareTracker.feedback`
            (off: ``feedback`` does nothing and the tracker is a plain Kalman tracker).
        feed_estimator: for drivers (command line, evaluation methods): feed the tracker's filtered
            poses, rather than the raw detections, to the estimator. The tracker itself ignores it.
        pseudo_region: the level at which a pseudo-measurement's Gaussian matches the region of a
            belief whose position is a Student-t (``ObjectBelief.position_dof``): its covariance is the
            belief's times ``region_radius_sq(pseudo_region, dof) / chi2.ppf(pseudo_region, 3)`` (0.86
            at 0.9 and 3 degrees of freedom), so that the two agree on the 90 % region. Matching the
            moments instead lets the t's tails, which reach beyond any error the fit saw, widen the
            Gaussian's core (the tracker's NEES while hidden fell under its band). A Gaussian belief is
            taken as it is.
        pseudo_std_floor: added in quadrature to the estimator's covariance of a pseudo-measurement
            (m), so that a belief with zero covariance (the paper's one-world reasoner) still gives an
            invertible ``R``.
        pseudo_fusion: ``"kalman"``: a pseudo-measurement is a Kalman update (the track fuses its
            constant-velocity prediction with the belief, as if they were independent);
            ``"replace"``: the track restarts at the belief (its mean and covariance, zero velocity
            with ``velocity_std``), so between the estimator's steps it stays put with a growing
            covariance. The belief was computed from the same detections and successive beliefs
            are correlated, so repeated Kalman updates make the track more confident than the
            belief it follows (seen in evaluation: a track at 3 cm std following a belief at 5 cm,
            with twice its error); ``"replace"`` (the default) avoids that.
    """

    accel_std: float = 5.3  # fitted: fit-priors --engines bullet,mujoco (99th percentile of carried accelerations)
    measurement_std: float = 0.01
    velocity_std: float = 0.5
    gate_probability: float = 0.99
    coast_time: float = 0.5
    reinit_after: float = 0.5
    use_feedback: bool = True
    feed_estimator: bool = False
    pseudo_std_floor: float = 0.002
    pseudo_fusion: str = "replace"
    pseudo_region: float = 0.9

    def __post_init__(self) -> None:
        for name in ("accel_std", "measurement_std", "velocity_std", "pseudo_std_floor"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"TrackerConfig.{name} must be a positive finite number, got {v!r}")
        for name in ("coast_time", "reinit_after"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"TrackerConfig.{name} must be >= 0 seconds, got {v!r}")
        if self.pseudo_fusion not in ("kalman", "replace"):
            raise ValueError(f"TrackerConfig.pseudo_fusion must be 'kalman' or 'replace', got {self.pseudo_fusion!r}")
        if not 0.0 < self.pseudo_region < 1.0:
            raise ValueError(f"TrackerConfig.pseudo_region must be in (0, 1), got {self.pseudo_region!r}")
        if not 0.0 < self.gate_probability < 1.0:
            raise ValueError(f"TrackerConfig.gate_probability must be in (0, 1), got {self.gate_probability!r}")

    @property
    def gate(self) -> float:
        """Gate on the squared Mahalanobis distance of a detection (chi-square, 3 dof)."""
        return float(chi2_quantile(self.gate_probability, 3))


def moments(ob, region: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(3,)`` and covariance ``(3, 3)`` of an object's whole belief (all its hypotheses: the
    moment-matched Gaussian a Kalman filter can take), from an
    :class:`~estimator.belief.ObjectBelief` (its ``position`` is the most probable hypothesis's).
    When the belief's position is a Student-t (finite ``position_dof``), the covariance is scaled
    so that the Gaussian's ``region`` ellipsoid is the t's (``TrackerConfig.pseudo_region``)."""
    mean = ob.position if ob.mean_position is None else ob.mean_position
    cov = np.asarray(ob.position_cov if ob.mean_position_cov is None else ob.mean_position_cov, float)
    if math.isfinite(ob.position_dof):
        cov = cov * (region_radius_sq(region, ob.position_dof) / chi2_quantile(region, 3))
    return np.asarray(mean, float).reshape(3), cov.reshape(3, 3)


@dataclass
class Track:
    """One object's filter and bookkeeping. ``kf.x (6, 1)``, ``kf.P (6, 6)``; times in s."""

    kf: KalmanFilter
    last_detected: float
    last_support: float
    orientation: np.ndarray | None = None
    rejected: int = 0
    source: str = "detection"

    @property
    def position(self) -> np.ndarray:
        """Filtered position ``(3,)`` m."""
        return self.kf.x[:3, 0].copy()

    @property
    def position_cov(self) -> np.ndarray:
        """Covariance ``(3, 3)`` m^2 of the position."""
        return self.kf.P[:3, :3].copy()

    @property
    def position_std(self) -> float:
        """Scalar position spread (m): square root of the mean of the position variances."""
        return float(np.sqrt(np.mean(np.diag(self.kf.P[:3, :3]))))

    def nees(self, truth_position) -> float:
        """Normalised estimation error squared of the position block: ``e' P33^-1 e`` with
        ``e = truth - position`` (``truth_position (3,)`` m); chi-square with 3 dof when consistent."""
        e = np.asarray(truth_position, float).reshape(3) - self.kf.x[:3, 0]
        return float(e @ np.linalg.solve(self.kf.P[:3, :3], e))


@dataclass
class Outcome:
    """What :meth:`PhysicsAwareTracker.update` did with each detection of a frame: ``action`` by id is
    ``"initialised"``, ``"accepted"``, ``"rejected"`` or ``"reinitialised"``; ``d2`` the squared
    Mahalanobis distance of the detection to the predicted position (absent for new tracks)."""

    action: dict[str, str] = field(default_factory=dict)
    d2: dict[str, float] = field(default_factory=dict)


class PhysicsAwareTracker:
    """One constant-velocity Kalman filter per object, kept alive by the estimator's belief.

    Args:
        config: the tracker's parameters.
        object_ids: objects the estimator's belief may start a track for (e.g. the scene's dynamic
            objects); ``None``: feedback only updates existing tracks. Detections always start one.

    Call order per frame: :meth:`update` (predicts to the frame's time, then gates and applies its
    detections), then :meth:`feedback` with the estimator's belief when it reasoned at that frame,
    then :meth:`to_frame` for the filtered poses.

    Gating policy: a detection is accepted when its squared Mahalanobis distance to the predicted
    position (``y = z - Hx``, ``S = HPH' + R``) is within :attr:`TrackerConfig.gate`. Outside it, the
    detection is rejected (counted in :attr:`rejections` and the track's ``rejected``) unless the
    object has had no accepted detection for longer than :attr:`TrackerConfig.reinit_after`, in which
    case the track is re-initialised at the detection (so a persistent jump, e.g. an object picked up
    during a dropout, is taken after that time).
    """

    def __init__(self, config: TrackerConfig | None = None, object_ids=None):
        self.config = config or TrackerConfig()
        self.object_ids = None if object_ids is None else tuple(object_ids)
        self.tracks: dict[str, Track] = {}
        self.t: float | None = None
        self.detected: frozenset[str] = frozenset()
        self.rejections = 0
        self.reinitialisations = 0
        self.pseudo_resets = 0
        self.dropped: list[tuple[float, str]] = []
        self._gate = self.config.gate

    # -- prediction -------------------------------------------------------------------------------
    def predict(self, t: float) -> None:
        """Predict every track to time ``t`` (s, not before the last time), then drop the tracks with
        neither detection nor pseudo-measurement for longer than ``coast_time``."""
        t = float(t)
        if self.t is not None and t < self.t:
            raise ValueError(f"tracker time must not go backwards: {t} s after {self.t} s")
        if self.t is not None and t > self.t:
            dt = t - self.t
            f, q = transition(dt), process_noise(dt, self.config.accel_std)
            for track in self.tracks.values():
                track.kf.predict(F=f, Q=q)
        self.t = t
        for oid in [o for o, tr in self.tracks.items() if t - tr.last_support > self.config.coast_time]:
            del self.tracks[oid]
            self.dropped.append((t, oid))

    # -- detections -------------------------------------------------------------------------------
    def measurement_cov(self, detection: Detection) -> np.ndarray:
        """``R (3, 3)`` m^2 of a detection: its ``position_std`` or the configured default, squared."""
        std = detection.position_std if detection.position_std is not None else self.config.measurement_std
        return std ** 2 * np.eye(3)

    def mahalanobis2(self, oid: str, z, r: np.ndarray) -> float:
        """Squared Mahalanobis distance of position ``z (3,)`` with covariance ``r (3, 3)`` to the
        predicted position of ``oid``'s track."""
        kf = self.tracks[oid].kf
        y = np.asarray(z, float).reshape(3) - (H_POS @ kf.x)[:, 0]
        s = H_POS @ kf.P @ H_POS.T + r
        return float(y @ np.linalg.solve(s, y))

    def new_filter(self, z, r: np.ndarray) -> KalmanFilter:
        """A filter at position ``z (3,)`` with zero velocity, ``P = diag(r, velocity_std^2 I)``."""
        from filterpy.kalman import KalmanFilter

        kf = KalmanFilter(dim_x=6, dim_z=3)
        kf.x = np.concatenate([np.asarray(z, float).reshape(3), np.zeros(3)]).reshape(6, 1)
        kf.P = np.zeros((6, 6))
        kf.P[:3, :3] = r
        kf.P[3:, 3:] = self.config.velocity_std ** 2 * np.eye(3)
        kf.H = H_POS.copy()
        kf.R = r.copy()
        return kf

    def update(self, frame: Frame) -> Outcome:
        """Predict to ``frame.t`` and apply its detections (gated, see the class docstring)."""
        self.predict(frame.t)
        t, out = frame.t, Outcome()
        for oid, det in frame.objects.items():
            r = self.measurement_cov(det)
            track = self.tracks.get(oid)
            if track is None:
                self.tracks[oid] = Track(self.new_filter(det.position, r), t, t, det.orientation)
                out.action[oid] = "initialised"
                continue
            d2 = self.mahalanobis2(oid, det.position, r)
            out.d2[oid] = d2
            if d2 <= self._gate:
                track.kf.update(det.position.reshape(3, 1), R=r)
                out.action[oid] = "accepted"
            elif t - track.last_detected > self.config.reinit_after:
                track.kf = self.new_filter(det.position, r)
                self.reinitialisations += 1
                out.action[oid] = "reinitialised"
            else:
                track.rejected += 1
                self.rejections += 1
                out.action[oid] = "rejected"
                continue
            track.last_detected = track.last_support = t
            track.source = "detection"
            if det.orientation is not None:
                track.orientation = det.orientation
        self.detected = frozenset(oid for oid, a in out.action.items() if a != "rejected")
        return out

    # -- physics feedback -------------------------------------------------------------------------
    def feedback(self, belief: Belief) -> list[str]:
        """Pseudo-measurements from the estimator's belief for every object it has that was not
        detected (accepted) in the last frame: a Kalman update with ``z (3,)`` and ``R = cov (3, 3) +
        pseudo_std_floor^2 I`` from the moments of the object's whole belief (:func:`moments`: with
        several hypotheses, their mixture's mean and covariance). A pseudo-measurement outside the gate
        (physics says the hidden object fell or was pushed, which a constant-velocity model with
        ``accel_std`` cannot follow) is not rejected: the track restarts at the belief's position with
        its covariance and zero velocity (counted in :attr:`pseudo_resets`), so the track always lies
        within the gate of the belief. An object without a track gets one at the belief's position
        when it is in ``object_ids``. The track's orientation becomes the belief's consensus
        orientation (physics knows better than the last detection how a hidden object turned). The
        belief's time must be the tracker's (call after :meth:`update`).

        The estimator was fed the same detections, so its position is correlated with the track's
        (the fused covariance is somewhat optimistic while an object has just been hidden; both
        forget the shared detections as the object stays hidden). Returns the ids updated.
        """
        if not self.config.use_feedback:
            return []
        if self.t is None or abs(belief.t - self.t) > 1e-9:
            raise ValueError(f"belief at t={belief.t} s does not match the tracker's time {self.t} s")
        done = []
        floor2 = self.config.pseudo_std_floor ** 2
        for oid, ob in belief.objects.items():
            if oid in self.detected:
                continue
            z, cov = moments(ob, self.config.pseudo_region)
            r = cov + floor2 * np.eye(3)
            r = 0.5 * (r + r.T)
            track = self.tracks.get(oid)
            if track is None:
                if self.object_ids is None or oid not in self.object_ids:
                    continue
                track = Track(self.new_filter(z, r), -np.inf, self.t,
                              np.asarray(ob.orientation, float))
                self.tracks[oid] = track
            elif self.config.pseudo_fusion == "replace":
                track.kf = self.new_filter(z, r)
            elif self.mahalanobis2(oid, z, r) <= self._gate:
                track.kf.update(z.reshape(3, 1), R=r)
            else:  # physics moved it beyond the constant-velocity model (a fall, a push): restart there
                track.kf = self.new_filter(z, r)
                self.pseudo_resets += 1
            track.orientation = np.asarray(ob.orientation, float)
            track.last_support = self.t
            track.source = "belief"
            done.append(oid)
        return done

    # -- output -----------------------------------------------------------------------------------
    def to_frame(self, t: float | None = None, hands: dict[str, np.ndarray] | None = None,
                 detected_only: bool = False) -> Frame:
        """The filtered poses as a :class:`Frame` at ``t`` (default: the tracker's time; a later
        ``t`` predicts first): position ``(3,)`` m, the orientation of the last detection or
        pseudo-measurement (``None`` if neither had one), ``position_std`` (m, :attr:`Track.position_std`); ``hands``
        passed through. ``detected_only``: only the tracks a detection updated in the last frame (what
        the estimator should take as perception: a coasting prediction is not one)."""
        if t is not None:
            self.predict(t)
        objects = {oid: Detection(tr.position, tr.orientation, tr.position_std) for oid, tr in self.tracks.items()
                   if not detected_only or oid in self.detected}
        return Frame(float(self.t if self.t is not None else 0.0), objects, dict(hands or {}))

    def nees(self, oid: str, truth_position) -> float:
        """Position NEES of ``oid``'s track against ``truth_position (3,)`` m (see :meth:`Track.nees`)."""
        return self.tracks[oid].nees(truth_position)
