"""What held objects do in the scene model: let go when they stop being perceived, and follow their
hand while unseen. Array functions over K particles and M objects (metres, seconds); randomness from
the ``numpy.random.Generator`` passed in.
"""
from __future__ import annotations

import math

import numpy as np

from actions.modes import is_free, is_held
from actions.push import PICK_T, lifted

from ..config import NoiseConfig
from ..observations import Frame
from ..worlds.held import hand_offset_walk
from .perception_memory import PerceptionMemory
from .step import Fall


def stratified_uniforms(K: int, M: int, rng: np.random.Generator) -> np.ndarray:
    """Uniforms ``(K, M)`` float64 on [0, 1), one column per object, stratified over the K
    particles: column m is ``(pi_m(k) + v_m) / K`` for a random permutation ``pi_m`` of the
    particles and one uniform ``v_m``. Each entry is uniform on [0, 1), and ``u < p`` holds for
    ``floor(K p)`` or ``ceil(K p)`` particles of a column."""
    offsets = rng.random(M)
    return np.stack([(rng.permutation(K) + offsets[m]) / K for m in range(M)], axis=1) if M else np.zeros((K, 0))


def held_targets(frame: Frame, poses: np.ndarray, modes: np.ndarray, detected: np.ndarray, perceived: np.ndarray,
                 dt: float, rng: np.random.Generator, hold_error: np.ndarray, memory: PerceptionMemory,
                 noise: NoiseConfig, carried: np.ndarray | None = None,
                 falling: Fall | None = None, detections: np.ndarray | None = None,
                 stale: np.ndarray | None = None, grip: np.ndarray | None = None,
                 hand_std: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Targets ``(K, M, 7)``, target velocities ``(K, M, 6)`` and offset errors ``(K, M, 3)``.

    Perceived objects at their perception (no noise: it would shake what a held object carries; free
    and seen still, with ``noise.still_average``, at the average of their still detections), with
    their perceived velocity (when ``carried (M,)`` is given, the teleports in motion: only those
    objects, teleported in motion now; the divergence test then carries the target on at that
    velocity, see :func:`~estimator.worlds.propagate.propagate_batch`; None: the paper's teleports); held objects not detected in this update follow the
    hand that held them when last detected, if it is tracked, at its offset then plus each particle's
    error (``hold_error (K, M, 3)`` before, walked by :func:`~estimator.worlds.held.hand_offset_walk`; so
    do those ``stale (M,)``, detected only in an earlier frame of this update, from their
    ``detections (M, 7)`` carried on to ``frame.t`` (by the hand; others seen moving, at their
    velocity: :meth:`~estimator.model.perception_memory.PerceptionMemory.detections_now`; None: none, and
    the memory's latest detections), else
    stay where they were perceived (while perceived; with ``carried`` given, where their last
    detection carried on at its perceived velocity puts them now: an object seen moving, a motion
    onset in ``memory.moving_since``, and then not seen goes on, not pinned where it was seen; a
    still one stays at its last detection, as perceived objects not held do) or where the particle
    has them, drifting by ``held_drift_std`` (m per sqrt(s)) when not perceived. Others: their pose
    in ``poses (K, M, 7)``.
    Objects perceived ``falling`` off an edge (:class:`~estimator.model.step.Fall`) are where their free
    fall has them at ``frame.t`` (horizontally on their line), moving at its mean vertical velocity
    over the update: the Release rule lets them go there, not where they were last seen. Those
    pushed out of view (a finite ``grip (K, M)``, :func:`push_grips`) slide around their hand
    (:func:`slide_around_hand`; travel within the noise of two tracked hand positions, ``hand_std``
    m each, is no direction)."""
    K, M = modes.shape
    new_error = np.zeros_like(hold_error)
    target = poses.copy()
    target_vel = np.zeros((K, M, 6))
    pidx = np.flatnonzero(perceived)
    now = memory.last_pose if detections is None else detections
    stale = np.zeros(M, dtype=bool) if stale is None else stale
    if len(pidx):
        target[:, pidx, :3] = now[pidx, :3]
        has_q = memory.last_has_orientation[pidx]
        target[:, pidx[has_q], 3:] = memory.last_pose[pidx[has_q], 3:]
        if noise.still_average:  # free and seen still: where its still detections average, not one
            # of them (a held one goes where the hand has it: its detection)
            still = perceived & ~stale & memory.seen_still
            kk, mm = np.nonzero(is_free(modes) & still[None, :])
            target[kk, mm, :3] = memory.still_position[mm]
        # with teleports in motion the divergence test carries a target on at its velocity: only
        # objects teleported in motion (placed at their detection now) have one
        with_vel = perceived if carried is None else perceived & carried
        vidx = np.flatnonzero(with_vel)
        target_vel[:, vidx, :3] = memory.perc_vel[vidx, :3]
        at_now = memory.position_at(frame.t) if carried is not None or falling is not None else None
        if carried is not None:  # not detected now: the detection ages, carried on at its velocity if
            # seen moving (a motion onset, as detections_now); a still object's fitted velocity is its
            # detections' noise (1 cm of noise fits a few cm/s), which would carry its target away
            cidx = np.flatnonzero(perceived & ~detected & np.isfinite(memory.moving_since))
            target[:, cidx, :3] = at_now[cidx]
            target_vel[:, cidx, :3] = memory.perc_vel[cidx, :3]
        if falling is not None:
            fidx = np.flatnonzero(falling.mask & perceived)
            target[:, fidx, :2] = at_now[fidx, :2]
            target[:, fidx, 2] = falling.z[fidx]
            target_vel[:, fidx, 2] = falling.mean_vz[fidx]
    held = is_held(modes) & (~detected | stale)[None, :]
    for m in np.flatnonzero(held.any(axis=0)):
        rows = held[:, m]
        hand = now[m, :3] if stale[m] else memory.hand_target(frame, m)
        if hand is not None:
            new_error[rows, m] = hand_offset_walk(hold_error[rows, m], dt, noise.held_offset_std,
                                                  noise.held_offset_time, rng)
            target[rows, m, :3] = hand + new_error[rows, m]
            slid = rows & np.isfinite(grip[:, m]) if grip is not None and not stale[m] else None
            if slid is not None and np.any(slid):
                at = memory.hand_position(memory.hold_hand[m])
                offset, _, _ = slide_around_hand(memory.hold_offset[m] + new_error[slid, m],
                                                 at - memory.hold_hand_position[m], grip[slid, m],
                                                 PUSH_END_SIGMAS * math.sqrt(2.0) * hand_std)
                target[slid, m, :3] = at + offset
        elif not perceived[m] and noise.held_drift_std > 0:
            target[rows, m, :3] += rng.normal(0.0, noise.held_drift_std * math.sqrt(dt), (int(rows.sum()), 3))
    return target, target_vel, new_error


def push_cannot_lift(target: np.ndarray, target_vel: np.ndarray, poses: np.ndarray, modes: np.ndarray,
                     holds: np.ndarray, detected: np.ndarray, lift: float) -> None:
    """In place on ``target (K, M, 7)`` and ``target_vel (K, M, 6)``: a held object that its episode
    has never lifted (:func:`never_lifted`: pushed or slid along its support) and that is not detected
    follows its hand along the support, not up: its target is no higher than where the particle
    has it (``poses (K, M, 7)``) and rises at no speed. A hand rising off a pushed object out of
    view leaves it there (:func:`pushes_ended`, once the rise is beyond the hand's noise); had it
    grasped it, the object shows when it is seen again."""
    rows = is_held(modes) & ~np.asarray(detected, dtype=bool)[None, :] & never_lifted(holds, lift)
    if np.any(rows):
        target[..., 2] = np.where(rows, np.minimum(target[..., 2], poses[..., 2]), target[..., 2])
        target_vel[..., 2] = np.where(rows, np.minimum(target_vel[..., 2], 0.0), target_vel[..., 2])


def slide_around_hand(offset: np.ndarray, travel: np.ndarray, grip: np.ndarray,
                      min_travel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a pushed object is relative to the hand that pushes it, out of view: quasi-static
    pushing of a round contact, horizontally.

    ``offset (n, 3)`` m: the object's centre minus the hand's when it was last detected (per
    particle); ``travel (3,)`` m: the hand's displacement since, taken as straight; ``grip (n,)`` in
    [0, 1]. A hand pushing an object touches it on the line of their centres, at angle ``theta`` to
    the direction it moves. Frictionless, the object can only move along that line, by what the hand
    advances along it: the offset turns away from the direction of travel,
    ``d theta / ds = sin(theta) / R`` (``R`` the offset's horizontal length), so
    ``tan(theta / 2)`` grows as ``exp(s / R)``: pushing a round object with a round hand is unstable,
    and it slides off the hand's side when ``theta`` reaches 90 degrees, where the hand no longer
    pushes it. Friction at the contact and a grasp slow that down, down to none (the object dragged
    along at its offset): ``grip`` scales the rate (1 frictionless, 0 gripped), since what the contact
    does is not seen. A hand that moves away from the object (``|theta0|`` at least 90 degrees) does
    not push it.

    Returns the offsets now ``(n, 3)`` (vertical part kept; those lost at 90 degrees), ``lost (n,)``
    bool (contact lost: the object stays where it slid off) and where each that slid off stays
    ``(n, 3)``, relative to the hand's position at the last detection (NaN for the others, and for
    those the hand moves away from: they stay where they are, a hand that pushed and drew back
    included). Below ``min_travel`` (m) of travel the direction is the hand's noise: offsets
    unchanged, nothing lost."""
    offset = np.asarray(offset, dtype=float)
    n = len(offset)
    at_loss = np.full((n, 3), np.nan)
    d = np.asarray(travel, dtype=float)[:2]
    s = float(np.hypot(d[0], d[1]))
    if n == 0 or not s > min_travel:
        return offset.copy(), np.zeros(n, dtype=bool), at_loss
    u = d / s
    v = np.array([-u[1], u[0]])
    a, b = offset[:, :2] @ u, offset[:, :2] @ v
    radius = np.hypot(a, b)
    theta0 = np.arctan2(b, a)
    sign = np.where(theta0 < 0, -1.0, 1.0)
    away = np.abs(theta0) >= 0.5 * math.pi
    half0 = np.tan(0.5 * np.minimum(np.abs(theta0), 0.5 * math.pi))
    rate = np.clip(np.asarray(grip, dtype=float), 0.0, 1.0) / np.maximum(radius, 1e-6)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        half = half0 * np.exp(rate * s)
        s_loss = np.where(rate > 0, np.log(1.0 / np.maximum(half0, 1e-12)) / rate, np.inf)
    lost = away | (half >= 1.0)
    theta = sign * 2.0 * np.arctan(np.minimum(half, 1.0))
    out = offset.copy()
    out[:, :2] = radius[:, None] * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)
    slid = lost & ~away
    at_loss[slid, :2] = s_loss[slid, None] * u + (sign[slid] * radius[slid])[:, None] * v
    at_loss[slid, 2] = offset[slid, 2]
    return out, lost, at_loss


def push_grips(grip: np.ndarray, pushed: np.ndarray, detected: np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
    """The grip (:func:`slide_around_hand`) of each particle's pushing contact ``(K, M)``: kept while
    the object is out of view, forgotten (NaN) when it is detected, drawn uniform on [0, 1)
    (stratified over the particles, :func:`stratified_uniforms`) for the ``pushed (K, M)`` entries
    that have none: nothing seen says how the contact slides, and the particles that keep the
    object where later evidence finds it are those that drew the right grip. Draws only when some
    entry needs one. A new array."""
    grip = np.array(grip, dtype=float)
    grip[:, np.asarray(detected, dtype=bool)] = np.nan
    need = np.asarray(pushed, dtype=bool) & np.isnan(grip)
    if np.any(need):
        grip[need] = stratified_uniforms(*grip.shape, rng)[need]
    return grip


def pushes_ended(modes: np.ndarray, holds: np.ndarray, before_z: np.ndarray, hand_z: np.ndarray,
                 in_tracked_hand: np.ndarray, lift: float) -> np.ndarray:
    """Held objects whose push has ended out of view: ``(K, M)`` bool.

    A held episode that never lifted its object (``holds (K, M, 6)``: :func:`actions.push.lifted`
    is false; its record has a Pick time) moved it along its support, pushed or slid, not grasped:
    a push cannot lift. When the tracked hand that moved such an undetected object
    (``in_tracked_hand (M,)``) would now carry it (``hand_z (M,)``, m: the height at which it follows
    the hand, NaN without one) more than ``lift`` (m) above ``before_z`` (``(M,)`` or ``(K, M)``, m:
    the height it was last seen at, in the tracker's frame as ``hand_z`` is: the hand has risen),
    the hand has left it: it is let go where it is. Physics, not a prior: no random draw, no
    weight. (Had the hand grasped it out of view, it shows when it is seen again.)"""
    with np.errstate(invalid="ignore"):
        rose = hand_z[None, :] - np.asarray(before_z, dtype=float) > lift
    return is_held(modes) & never_lifted(holds, lift) & rose & np.asarray(in_tracked_hand, dtype=bool)[None, :]


def never_lifted(holds: np.ndarray, lift: float) -> np.ndarray:
    """``(K, M)`` bool: held episodes (``holds (K, M, 6)``, with a Pick time) that never lifted their
    object more than ``lift`` (m): pushed or slid along its support."""
    return ~lifted(holds, lift) & np.isfinite(holds[..., PICK_T])


PUSH_END_SIGMAS = 3.0
"""A pushed object's hand has risen off it when it rose more than ``push_lift`` plus this many
standard deviations of the difference of two tracked hand heights (``HandConfig.measurement_std``
each): a hand tracked to 1 cm jitters by 2 cm between two updates, and a push must not end on that."""


