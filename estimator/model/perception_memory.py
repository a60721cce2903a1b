"""The perception memory: what the detector said about each object, shared by all particles.

M objects; positions in metres, quaternions ``(x, y, z, w)``, times and durations in seconds,
velocities in m/s. The memory holds the latest detection of each object (pose, time, std, and
velocity: the least-squares line through its recent detections, with the slope's standard error),
the tracked hand nearest to it and its offset to that hand (averaged over the frames that show both:
:mod:`estimator.model.hands`), each tracked hand's filtered position, a short history of detections (for the Place rule and the line) and
the perception at the previous reasoning step (for teleports and for the velocity over a reasoning
period).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from physics.scene import Scene

from ..config_sections import RELEASE_DOWN_SPEED, HandConfig, ReasonerConfig
from ..observations import Frame
from .detection_noise import DetectionNoise, onset_distance
from .hand_memory import HandsInMemory
from .hands import HandFilter
from .tracks import dwell_back, fit_acceleration, fit_line, free_fall, rested

MOTION_ONSET = 0.015
"""m: an object still until now starts moving when a detection lies this far from where it was still
(the average of its still detections), or farther where the tracker's noise asks for it
(:meth:`PerceptionMemory.onset`); it started at its last detection closer than that."""
ACCEL_WINDOW = 1.0
"""s: the longest stretch of a roll whose detections are fitted for its deceleration
(:meth:`PerceptionMemory.acceleration`); detections are kept at least this long."""
VELOCITY_WINDOW = 0.2
"""s: an object's perceived velocity is the least-squares slope of its detections over this long (since
its last gap longer than ``t_perceived``): a difference of two frames 1/30 s apart turns a few
millimetres of detection noise into tenths of a metre per second, which a hidden object then keeps."""
STILL_FRAMES = 30
"""A still object's position is the mean of its still detections, the latest :data:`STILL_FRAMES`
weighing most (an exponential average of weight ``max(1 / n, 1 / STILL_FRAMES)``): it does not follow
a slow slide. Its standard error is the detection noise over ``sqrt(min(n, STILL_EFFECTIVE))``."""
STILL_EFFECTIVE = 2 * STILL_FRAMES - 1  # the effective count of those weights once they are 1 / STILL_FRAMES


class PerceptionMemory(HandsInMemory):
    """Latest perception of each object of ``scene`` (see the module docstring).

    Args:
        scene: the scene (object ids; static objects' detections are ignored).
        poses: ``(M, 7)`` initial poses (known objects at their scene pose, the others parked).
        reasoner: ``t_perceived``, ``d_perc_prev`` and the Place rule's parameters.
        follow_hands: whether held objects follow the tracked hand (:meth:`following_hand`).
        from_onset: whether the perceived velocity's line starts at the motion onset
            (``moving_since``); False: over the whole window (the paper's mode keeps it).
        hands: how tracked hands and offsets to them are read (:class:`~estimator.config.HandConfig`).

    Arrays (all ``(M, ...)``): ``last_pose (M, 7)``, ``last_has_orientation`` bool, ``last_seen`` (s; -inf: never),
    ``last_std`` (m; NaN: the detector gave none), ``perc_vel (M, 6)`` (linear part the least-squares slope of the
    detections over :data:`VELOCITY_WINDOW`, m/s; angular part 0), ``perc_vel_sxx (M,)`` (s^2, the spread of those
    detections' times about their mean: the slope's standard error is the detection noise over its square root; 0:
    no slope), ``pose_at_tick (M, 7)`` and ``seen_at_tick`` (``last_pose``, ``last_seen`` at the previous reasoning
    step), ``perceived_prev`` bool (then), ``hold_hand`` (name of the tracked hand near each object when last
    detected, or None), ``hold_offset (M, 3)`` (object minus raw hand position, m, averaged over the frames that
    showed both, :func:`~estimator.model.hands.average_offset`), ``still_position (M, 3)`` (m, average detection
    while the object is still, of ``still_count (M,)`` detections; NaN: not seen still) and ``moving_since (M,)``
    (s, the time a still object started moving, :meth:`onset`, until it is at rest again; NaN: still).
    """

    def __init__(self, scene: Scene, poses: np.ndarray, reasoner: ReasonerConfig, follow_hands: bool,
                 from_onset: bool = True, hands: HandConfig | None = None):
        M = len(scene.objects)
        self.scene = scene
        self.reasoner = reasoner
        self.follow_hands = follow_hands
        self.from_onset = from_onset
        self.hand_config = hands or HandConfig()
        self.static = np.array([o.static for o in scene.objects], dtype=bool)
        self.last_pose = poses.copy()
        self.last_has_orientation = np.zeros(M, dtype=bool)
        self.last_seen, self.last_std = np.full(M, -np.inf), np.full(M, np.nan)
        self._perc_vel = np.zeros((M, 6))
        self._sxx = np.zeros(M)
        self._line_xy = np.zeros((M, 2))  # the fitted line's horizontal position at the last detection
        self._scatter = np.full(M, np.nan)
        self.noise = DetectionNoise()  # the tracker's position noise, from the scatters about the lines
        self._fit_due = np.zeros(M, dtype=bool)  # detected since their line was last fitted
        self._segment_start = np.full(M, -np.inf)
        self.pose_at_tick = poses.copy()
        self.perceived_prev = np.zeros(M, dtype=bool)
        self._init_hands(M)
        self._prev_tick_vel = np.zeros((M, 3))
        self.seen_at_tick = np.full(M, -np.inf)
        self._history: list[deque] = [deque() for _ in range(M)]
        self.still_position, self.moving_since = np.full((M, 3), np.nan), np.full(M, np.nan)
        self.still_count = np.zeros(M, dtype=int)
        self.workspace = scene.workspace_bounds()
        self.rejected = 0

    @property
    def M(self) -> int:
        return len(self.static)

    def admit(self, frame: Frame) -> Frame:
        """The frame without the detections and hands outside the scene's workspace
        (:meth:`~physics.scene.Scene.workspace_bounds`: a position of 1e308 m, or 50 m under the
        floor, is an outlier, never a belief); each one dropped is counted in :attr:`rejected`."""
        lo, hi = self.workspace

        def inside(p) -> bool:
            return bool(np.all(p >= lo) and np.all(p <= hi))

        ids = self.scene.object_ids  # an unknown id is left for record() to report
        objects = {oid: d for oid, d in frame.objects.items() if oid not in ids or inside(d.position)}
        hands = {h: p for h, p in frame.hands.items() if inside(np.asarray(p))}
        dropped = len(frame.objects) - len(objects) + len(frame.hands) - len(hands)
        if not dropped:
            return frame
        self.rejected += dropped
        return Frame(frame.t, objects, hands, frame.line, frame.cameras)

    # -- a frame --------------------------------------------------------------------------------------
    def record(self, frame: Frame) -> np.ndarray:
        """Store the frame's detections; returns the detected mask ``(M,)`` (dynamic objects only).
        Raises ValueError for an object id the scene does not have."""
        detected = np.zeros(self.M, dtype=bool)
        hr = self.reasoner
        for name, p in frame.hands.items():
            self._hands.setdefault(name, HandFilter(self.hand_config)).update(frame.t, p)
        for oid, det in frame.objects.items():
            try:
                m = self.scene.index(oid)
            except KeyError:
                raise ValueError(f"frame at t={frame.t}: unknown object id {oid!r}") from None
            if self.static[m]:
                continue
            detected[m] = True
            gap = frame.t - self.last_seen[m]
            self._track_motion(m, frame.t, det.position, gap)
            if not 0 < gap <= hr.t_perceived:
                self._segment_start[m] = frame.t  # first sighting or back after a gap: no velocity yet
            self.last_pose[m, :3] = det.position
            if det.orientation is not None:
                self.last_pose[m, 3:] = det.orientation
            self.last_has_orientation[m] = det.orientation is not None
            self.last_std[m] = det.position_std if det.position_std is not None else np.nan
            self.last_seen[m] = frame.t
            hist = self._history[m]
            hist.append((frame.t, tuple(det.position.tolist()),
                         None if det.orientation is None else tuple(det.orientation.tolist())))
            while hist and hist[0][0] < frame.t - max(2.0 * hr.place_dwell + 0.1, VELOCITY_WINDOW, ACCEL_WINDOW):
                hist.popleft()
            self._fit_due[m] = True
            self._nearest_hand(frame, m)
        return detected

    # -- the fitted lines (fitted when read, once per object detected since: not at every frame) -------
    def _fit_pending(self) -> None:
        for m in np.flatnonzero(self._fit_due):
            self._perc_vel[m, :3], self._sxx[m], self._line_xy[m], self._scatter[m], dof = \
                self._fit_velocity(m, self.last_seen[m])
            self.noise.add(self._scatter[m], dof)
        self._fit_due[:] = False

    @property
    def perc_vel(self) -> np.ndarray:
        """``(M, 6)`` m/s: the perceived velocities (see the class docstring); writable in place."""
        self._fit_pending()
        return self._perc_vel

    @property
    def perc_vel_sxx(self) -> np.ndarray:
        """``(M,)`` s^2: the spread of the fitted detections' times (see the class docstring)."""
        self._fit_pending()
        return self._sxx

    @property
    def perc_vel_scatter(self) -> np.ndarray:
        """``(M,)`` m: the fitted detections' horizontal scatter about their line (NaN: under three)."""
        self._fit_pending()
        return self._scatter

    def teleported(self, at_rest: np.ndarray, falling: np.ndarray) -> None:
        """The perceived velocities of the objects teleported now: none for those put at rest
        (``at_rest (M,)`` bool), no vertical part for those ``falling (M,)`` bool off an edge (their
        fall gives it: :meth:`set_vertical_velocity`)."""
        vel = self.perc_vel
        vel[at_rest] = 0.0
        vel[falling, 2] = 0.0

    def set_vertical_velocity(self, objects: np.ndarray, vz: np.ndarray) -> None:
        """The perceived vertical velocity of ``objects (M,)`` bool is ``vz (M,)`` m/s (a fall's)."""
        self.perc_vel[objects, 2] = vz[objects]

    def velocity_std(self, position_std: float) -> np.ndarray:
        """Standard error ``(M,)`` (m/s) of each perceived velocity per axis: the detection noise over
        the square root of :attr:`perc_vel_sxx`; 0 where there is no slope. The noise is the detector's
        ``position_std`` where it gave one, else the detections' horizontal scatter about their line
        (:attr:`perc_vel_scatter`, from three detections on) up to ``position_std`` (m, the model's
        perception noise, also used with two detections)."""
        sigma = self._noise_std(position_std)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self._sxx > 0, sigma / np.sqrt(self._sxx), 0.0)

    def _noise_std(self, position_std: float) -> np.ndarray:
        """``(M,)`` m: each object's detection noise per axis (see :meth:`velocity_std`)."""
        self._fit_pending()
        scatter = np.where(np.isfinite(self._scatter), np.minimum(self._scatter, position_std), position_std)
        return np.where(np.isfinite(self.last_std), self.last_std, scatter)

    def acceleration(self, m: int, since: float, position_std: float) -> tuple[np.ndarray, float, float] | None:
        """Object m's horizontal acceleration over its detections from ``since`` (s) to its latest one,
        at most :data:`ACCEL_WINDOW` back and within its current segment: ``(a (2,) m/s^2, standard
        error per axis m/s^2, span s)`` (:func:`~estimator.model.tracks.fit_acceleration`, the noise
        as :meth:`velocity_std`'s); None when too few detections span too short a time."""
        t = float(self.last_seen[m])
        start = max(since, t - ACCEL_WINDOW, float(self._segment_start[m]))
        return fit_acceleration(self._history[m], start, t, float(self._noise_std(position_std)[m]))

    def _fit_velocity(self, m: int, t: float) -> tuple[np.ndarray, float, np.ndarray, float]:
        """Least-squares line through object m's detections over the :data:`VELOCITY_WINDOW` up to its
        latest one at ``t`` (s), since its segment started and (``from_onset``) since it started
        moving (its last still detection on: a line through the still ones before a flick lags it):
        the slope ``(3,)`` (m/s), the spread of the detection times ``sxx`` (s^2), the line's
        horizontal position at ``t`` ``(2,)`` (m) and
        the detections' horizontal scatter about it (m, RMS per axis over ``n - 2`` degrees of
        freedom; NaN under three detections) and those degrees of freedom; for fewer than two
        detections ``(0, 0, the latest detection, NaN, 0)``."""
        since = max(t - VELOCITY_WINDOW, self._segment_start[m])
        if self.from_onset and np.isfinite(self.moving_since[m]):
            since = max(since, self.moving_since[m])
        return fit_line(self._history[m], since - 1e-9, t)

    def _track_motion(self, m: int, t: float, position: np.ndarray, gap: float) -> None:
        """Motion onset of object m from its detection at ``position`` (m) at ``t`` (s), ``gap`` (s)
        after the previous one (before it is stored): a still object (its average still position
        known) moves when the detection is :meth:`onset` away (``moving_since`` = the previous
        detection's time); a moving one is still again once its detections over a ``place_dwell``
        since it started moving stayed within :meth:`onset` (checked on the history before
        this detection, and this detection against the one a ``place_dwell`` before it: a box a hand
        starts moving slowly after a pause is not still; still again, it restarts the average here). After a loss (``gap`` over
        ``t_perceived``) nothing is known: the object starts still where seen."""
        still, since, last = self.still_position[m], self.moving_since[m], self.last_seen[m]
        onset = self.onset(m)
        if not gap <= self.reasoner.t_perceived or np.isnan(still[0]) or (
                last - since >= self.reasoner.place_dwell and self._rested(m, last, onset)
                and self._stayed(m, last, position, onset)):
            self.still_position[m], self.moving_since[m], self.still_count[m] = position, np.nan, 1
        elif np.isnan(self.moving_since[m]):
            if math.dist(still, position) > onset:
                self.moving_since[m] = self.last_seen[m]
            else:
                self.still_count[m] += 1
                self.still_position[m] = still + max(1.0 / self.still_count[m], 1.0 / STILL_FRAMES) * (position - still)

    # -- queries at a reasoning step ------------------------------------------------------------------
    @property
    def seen_still(self) -> np.ndarray:
        """``(M,)`` bool: objects seen still: a still position known and no motion onset since."""
        return np.isnan(self.moving_since) & np.isfinite(self.still_position[:, 0])

    def perceived(self, t: float) -> np.ndarray:
        """Dynamic objects ``(M,)`` seen within ``t_perceived`` of ``t``."""
        return ~self.static & (t - self.last_seen <= self.reasoner.t_perceived + 1e-9)

    def position_at(self, t: float) -> np.ndarray:
        """Perceived positions ``(M, 3)`` (m) carried from each object's last detection to time ``t``
        (s) at its perceived velocity (``perc_vel``; zero for an object teleported at rest): where
        an object seen moving was at the start of an update whose detections it is teleported to.
        Moving horizontally, it is carried along the detections' fitted line (the slope is their
        average velocity, at the middle of the window: one reasoning period back, an update's start,
        from where physics slows a rolling ball down as it should); else from its last detection."""
        lag = np.where(np.isfinite(self.last_seen), t - self.last_seen, 0.0)  # never seen: no lag
        vel = self.perc_vel[:, :3]
        base = self.last_pose[:, :3].copy()
        on_line = np.any(vel[:, :2] != 0.0, axis=1)
        base[on_line, :2] = self._line_xy[on_line]
        return base + vel * lag[:, None]

    def free_fall(self, times, gravity: float, position_std: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Heights ``(T, M)`` (m) and vertical velocities ``(T, M)`` (m/s) at ``times (T,)`` (s) of a
        free fall through each object's last two detections of its segment, for ``gravity`` (m/s^2,
        negative), and that velocity's standard error ``(M,)`` (m/s): ``sqrt(2)`` times the detection
        noise (the detector's ``position_std``, else ``position_std`` m) over their interval
        (:func:`~estimator.model.tracks.free_fall`; carried back to before it began, the object
        was still on its support or had just left it, at rest at the fall's top, from where physics
        takes it off its edge). NaN for objects with fewer than two detections in their segment or
        not moving down at the last one."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        z = np.full((len(times), self.M), np.nan)
        vz = np.full((len(times), self.M), np.nan)
        err = np.full(self.M, np.nan)
        g = -float(gravity)
        sigma = np.where(np.isfinite(self.last_std), self.last_std, position_std)
        for m in range(self.M):
            fall = free_fall(self._history[m], self._segment_start[m], times, g, sigma[m])
            if fall is not None:
                z[:, m], vz[:, m], err[m] = fall
        return z, vz, err

    def jumped(self, noise_aware: bool = False) -> np.ndarray:
        """Objects ``(M,)`` whose perceived position moved by more than ``d_perc_prev`` since the
        previous reasoning step (Algorithm 1); ``noise_aware``: and further than two detections of a
        still object lie apart by noise but once in a thousand times (``onset_distance`` of sqrt(2)
        times the noise :meth:`onset` takes: the detector's, else the tracker's measured so far)."""
        d, floor = np.linalg.norm(self.last_pose[:, :3] - self.pose_at_tick[:, :3], axis=1), self.reasoner.d_perc_prev
        if not noise_aware:
            return d > floor
        std = np.where(np.isfinite(self.last_std), self.last_std, self.noise.std)
        return d > np.array([onset_distance(math.sqrt(2.0) * float(s), floor) for s in std])

    def stale_in_hand(self, frame: Frame, held: np.ndarray) -> np.ndarray:
        """Objects ``(M,)`` last detected before ``frame.t`` (the update's later frames missed them)
        whose hand then is tracked in ``frame``: the hand says where they are now. Only those some
        particle holds (``held (M,)`` bool) or seen moving (a motion onset): a hand does not carry a
        still object it is near (a tray it put a mug in). Not those moving down at
        :data:`~estimator.config.RELEASE_DOWN_SPEED` or faster (:meth:`tick_velocity`): let go."""
        out = self.following_hand(frame) & (self.last_seen < frame.t - 1e-9)
        out &= self.tick_velocity()[:, 2] >= -RELEASE_DOWN_SPEED  # not falling
        return out & (held | np.isfinite(self.moving_since))

    def detections_now(self, stale: np.ndarray, t: float, aged: np.ndarray | None = None) -> np.ndarray:
        """The latest detections ``(M, 7)`` carried on to the update's frame at ``t`` (s): those of
        ``stale (M,)`` (:meth:`stale_in_hand`) with their hand (a cup carried at 1.3 m/s is 9 cm on
        two frames after its last detection), by the hand's displacement since, between its filtered
        positions (:meth:`hand_position`, as :meth:`hand_travel`; a raw hand position is noisier
        than a detection); the other ``aged (M,)`` ones detected before ``t`` and seen moving at
        their perceived velocity (:meth:`position_at`: a ball flicked at 1 m/s is 3 cm on one frame
        after its last detection). Call after the frame is recorded."""
        out = self.last_pose.copy()
        for m in np.flatnonzero(stale):
            out[m, :3] += self.hand_position(self.hold_hand[m]) - self.hold_hand_position[m]
        if aged is not None:
            carry = aged & ~stale & np.isfinite(self.moving_since) & (self.last_seen < t - 1e-9)
            if np.any(carry):
                out[carry, :3] = self.position_at(t)[carry]
        return out

    def tick_velocity(self) -> np.ndarray:
        """Perceived velocity ``(M, 3)`` (m/s) over the last reasoning period (smoother than
        frame-to-frame differences): from the detections used at the previous step to the latest."""
        ok = np.isfinite(self.last_seen) & np.isfinite(self.seen_at_tick)
        gap = np.where(ok, self.last_seen - np.where(ok, self.seen_at_tick, 0.0), 0.0)
        ok &= gap > 1e-6
        vel = np.zeros((self.M, 3))
        vel[ok] = (self.last_pose[ok, :3] - self.pose_at_tick[ok, :3]) / gap[ok, None]
        return vel

    def previous_tick_velocity(self) -> np.ndarray:
        """The tick velocity ``(M, 3)`` (m/s) of the previous reasoning step (0 for objects not detected then)."""
        return self._prev_tick_vel.copy()

    def vertical_acceleration(self, vel: np.ndarray, dt: float) -> np.ndarray:
        """Vertical acceleration ``(M,)`` (m/s^2) from the tick velocity ``vel (M, 3)`` of the previous
        step (0 for objects not detected then) to ``vel``, ``dt`` seconds later."""
        return (vel[:, 2] - self._prev_tick_vel[:, 2]) / max(dt, 1e-9)

    def at_rest(self, t: float) -> np.ndarray:
        """Objects ``(M,)`` detected within ``place_dwell`` of ``t`` whose detections over the
        ``place_dwell`` seconds up to their latest one moved less than ``place_speed * place_dwell``
        and turned less than ``place_spin * place_dwell``."""
        return np.array([self._rested(m, t) for m in range(self.M)], dtype=bool)

    def shifted(self, distance: float) -> np.ndarray:
        """Objects ``(M,)`` perceived moving (a motion onset since they were still) whose latest
        detection lies more than ``distance`` (m) horizontally from where they were still: moved
        along their support, not a perception spike (a detection sunk into the table)."""
        shift = np.linalg.norm(self.last_pose[:, :2] - self.still_position[:, :2], axis=1)
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.moving_since) & (shift > distance)

    def mean_positions(self, t: float, span: float) -> np.ndarray:
        """Mean detected position ``(M, 3)`` (m) of each object over the ``span`` seconds up to ``t``
        (NaN for an object without a detection then)."""
        out = np.full((self.M, 3), np.nan)
        for m, hist in enumerate(self._history):
            recent = [h[1] for h in hist if h[0] >= t - span - 1e-9]
            if recent:
                out[m] = np.mean(recent, axis=0)
        return out

    def onset(self, m: int) -> float:
        """Distance (m) a detection of still object m must stray from its resting position to say it
        moved: :func:`~estimator.model.detection_noise.onset_distance` of the noise of its latest detection
        (the detector's ``position_std`` where it gave one, else the tracker's noise measured so far,
        :attr:`noise`), never under :data:`MOTION_ONSET`."""
        std = self.last_std[m] if math.isfinite(self.last_std[m]) else self.noise.std
        return onset_distance(std, MOTION_ONSET)

    def _stayed(self, m: int, t: float, position: np.ndarray, distance: float) -> bool:
        """Whether object m's new detection at ``position`` (m) is within ``distance`` (m, its
        :meth:`onset`) of its stored detection ``place_dwell`` before ``t`` (s, its latest one; True
        when there is none): a box that a hand starts moving slowly looks still before, and is not."""
        old = self._dwell_back(m, t)
        return old is None or math.dist(old[1], position) <= distance

    def _dwell_back(self, m: int, t: float) -> tuple | None:
        """Object m's latest stored detection ``(t, position, orientation)`` at least ``place_dwell``
        before ``t`` (s); None when there is none (:func:`~estimator.model.tracks.dwell_back`)."""
        return dwell_back(self._history[m], t, self.reasoner.place_dwell)

    def _rested(self, m: int, t: float, distance: float | None = None) -> bool:
        """:meth:`at_rest` for object m at time ``t`` (s), on the detections stored so far; with
        ``distance`` (m), the detections must also have moved less than that
        (:func:`~estimator.model.tracks.rested`)."""
        hr = self.reasoner
        return rested(self._history[m], t, hr.place_dwell, hr.place_speed, hr.place_spin, distance)

    # -- end of a reasoning step ----------------------------------------------------------------------
    def end_tick(self, perceived: np.ndarray, detected: np.ndarray, tick_vel: np.ndarray) -> None:
        """Remember this step's perception: ``perceived (M,)``, and the tick velocity ``(M, 3)`` of the
        ``detected (M,)`` objects (for the next :meth:`vertical_acceleration`)."""
        self._prev_tick_vel = np.where(detected[:, None], tick_vel, 0.0)
        self.perceived_prev = perceived
        self.pose_at_tick = self.last_pose.copy()
        self.seen_at_tick = self.last_seen.copy()
