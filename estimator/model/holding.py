"""What held objects do in the scene model: let go when they stop being perceived, and follow their
hand while unseen. Array functions over K particles and M objects (metres, seconds); randomness from
the ``numpy.random.Generator`` passed in.
"""
from __future__ import annotations

import math

import numpy as np

from actions.modes import FREE, HELD, PLACE, RELEASE, ModePriors
from actions.push import PICK_T, lifted

from ..config import NoiseConfig
from ..observations import Frame
from ..worlds.held import hand_offset_walk
from .motion import drop_heights
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
                 noise: NoiseConfig, moving_teleports: bool,
                 teleported: np.ndarray | None = None,
                 falling: Fall | None = None, detections: np.ndarray | None = None,
                 stale: np.ndarray | None = None, grip: np.ndarray | None = None,
                 hand_std: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Targets ``(K, M, 7)``, target velocities ``(K, M, 6)`` and offset errors ``(K, M, 3)``.

    Perceived objects at their perception (no noise: it would shake what a held object carries), with
    their perceived velocity (with ``moving_teleports``, only those ``teleported (M,)`` now; the
    divergence test then carries the target on at that velocity, see
    :func:`~estimator.worlds.propagate.propagate_batch`); held objects not detected in this update follow the
    hand that held them when last detected, if it is tracked, at its offset then plus each particle's
    error (``hold_error (K, M, 3)`` before, walked by :func:`~estimator.worlds.held.hand_offset_walk`; so
    do those ``stale (M,)``, detected only in an earlier frame of this update, from their
    ``detections (M, 7)`` carried on to ``frame.t`` (by the hand; others seen moving, at their
    velocity: :meth:`~estimator.model.perception_memory.PerceptionMemory.detections_now`; None: none, and
    the memory's latest detections), else
    stay where they were perceived (while perceived; with ``moving_teleports``, where their last
    detection carried on at its perceived velocity puts them now: an object seen moving and then not
    seen goes on, not pinned where it was seen) or where the particle has them, drifting by
    ``held_drift_std`` (m per sqrt(s)) when not perceived. Others: their pose in ``poses (K, M, 7)``.
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
        # with moving_teleports the divergence test carries a target on at its velocity: only
        # objects teleported in motion (placed at their detection now) have one
        with_vel = perceived
        if moving_teleports:
            with_vel = perceived & (np.zeros(M, bool) if teleported is None else teleported)
        vidx = np.flatnonzero(with_vel)
        target_vel[:, vidx, :3] = memory.perc_vel[vidx, :3]
        at_now = memory.position_at(frame.t) if moving_teleports or falling is not None else None
        if moving_teleports:  # not detected now: the detection ages, carried on at its velocity
            cidx = np.flatnonzero(perceived & ~detected)
            target[:, cidx, :3] = at_now[cidx]
            target_vel[:, cidx, :3] = memory.perc_vel[cidx, :3]
        if falling is not None:
            fidx = np.flatnonzero(falling.mask & perceived)
            target[:, fidx, :2] = at_now[fidx, :2]
            target[:, fidx, 2] = falling.z[fidx]
            target_vel[:, fidx, 2] = falling.mean_vz[fidx]
    held = (modes == HELD) & (~detected | stale)[None, :]
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
    has never lifted (:func:`_pushed`: pushed or slid along its support) and that is not detected
    follows its hand along the support, not up: its target is no higher than where the particle
    has it (``poses (K, M, 7)``) and rises at no speed. A hand rising off a pushed object out of
    view leaves it there (:func:`pushes_ended`, once the rise is beyond the hand's noise); had it
    grasped it, the object shows when it is seen again."""
    rows = (modes == HELD) & ~np.asarray(detected, dtype=bool)[None, :] & _pushed(holds, lift)
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


def hidden_places(hidden_at: np.ndarray, hidden_t: np.ndarray, hidden_n: np.ndarray, poses: np.ndarray,
                  hidden: np.ndarray, reset: np.ndarray, t: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each particle's held object was while its hand hid it: a uniform sample over those
    updates (reservoir sampling), to let it go there later (:func:`release_behind_cover`).

    ``hidden_at (K, M, 3)`` m, ``hidden_t (K, M)`` s and ``hidden_n (K, M)`` int32 (updates counted)
    before; ``poses (K, M, 7)`` now; ``hidden (K, M)``: held objects out of the camera's view in this
    update; ``reset (K, M)``: entries that start again (not held, or detected). Returns the three
    arrays after this update (copies). One uniform draw per entry, whatever is hidden."""
    u = rng.random(hidden_n.shape)
    n = hidden_n.astype(np.int32, copy=True)
    n[hidden] += 1
    take = hidden & (u * np.maximum(n, 1) < 1.0)  # the n-th hidden update replaces the sample w.p. 1/n
    at, tt = hidden_at.copy(), hidden_t.copy()
    at[take] = poses[take][:, :3]
    tt[take] = t
    n[reset] = 0
    return at, tt, n


def lowest_hidden_place(low_at: np.ndarray, low_t: np.ndarray, hidden_n: np.ndarray, poses: np.ndarray,
                        hidden: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each particle's held object was lowest while its hand hid it: where a person who put it
    down behind cover would have let go of it (:func:`release_behind_cover`).

    Arrays as in :func:`hidden_places`, ``hidden_n`` its count before this update (0: a first hidden
    update, which is taken whatever its height); the place and time are replaced when the object is
    lower (m, height of its pose) than at the kept place. Deterministic. Returns the place and time
    after this update (copies)."""
    take = hidden & ((hidden_n == 0) | (poses[..., 2] < low_at[..., 2]))
    at, tt = low_at.copy(), low_t.copy()
    at[take] = poses[take][:, :3]
    tt[take] = t
    return at, tt


def resting_place(rest_at: np.ndarray, rest_t: np.ndarray, poses: np.ndarray, hidden: np.ndarray,
                  supported: np.ndarray, reset: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Where and when each particle's held object last rested on a support (``supported (K, M)``)
    while out of view and undetected in its hand (``hidden (K, M)``; unlike :func:`hidden_places`,
    also while it still counts as perceived): where a hand that sets it down leaves it
    (:func:`set_down_behind_cover`). ``rest_at (K, M, 3)`` m and ``rest_t (K, M)`` s (-inf: none)
    before; ``reset (K, M)``: entries that start again. Returns both after this update (copies)."""
    take = hidden & supported
    at, tt = rest_at.copy(), rest_t.copy()
    at[take] = poses[take][:, :3]
    tt[take] = t
    tt[reset] = -np.inf
    return at, tt


def release_behind_cover(modes: np.ndarray, unseen_in_view: np.ndarray, hidden_n: np.ndarray,
                         in_tracked_hand: np.ndarray, priors: ModePriors, noise: NoiseConfig,
                         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Objects let go while their hand hid them, decided when the hand shows in view without them.

    A held object in a tracked hand (``in_tracked_hand (M,)``, not perceived) that was out of view
    for some updates (``hidden_n > 0``) and, at the last update, in view for the first time without
    being detected (``unseen_in_view == 1``) is either still held, the person hiding it (it has
    paid ``L = h + (1 - h) miss_prob`` for that update, see
    :func:`~estimator.model.likelihood.negative_evidence_log_likelihood`), or was let go earlier, out of
    view (prior ``r = release_hidden``; nothing unseen to explain). Each such entry is drawn from
    that posterior: let go with probability ``r / (r + (1 - r) L)``, and every such particle's
    weight is multiplied by ``(r + (1 - r) L) / L`` (the marginal likelihood over what it already
    paid): a correct importance move. Returns the entries let go ``(K, M)`` bool and the log-weight
    factors ``(K,)``. One uniform draw per entry. Nothing happens when ``hand_occlusion`` is 1 (held
    objects exempt from negative evidence, as in the paper's reasoner)."""
    K, M = modes.shape
    u = rng.random((K, M))
    if noise.hand_occlusion >= 1.0:
        return np.zeros((K, M), dtype=bool), np.zeros(K)
    h, r = noise.hand_occlusion, priors.release_hidden
    cand = (modes == HELD) & (unseen_in_view == 1) & (hidden_n > 0) & np.asarray(in_tracked_hand, bool)[None, :]
    L = h + (1.0 - h) * noise.miss_prob
    p = r / (r + (1.0 - r) * L)
    factor = math.log((r + (1.0 - r) * L) / L)
    return cand & (u < p), factor * cand.sum(axis=1)


def set_down_behind_cover(modes: np.ndarray, rest_at: np.ndarray, rest_t: np.ndarray, before_z: np.ndarray,
                          hand_z: np.ndarray, in_tracked_hand: np.ndarray, priors: ModePriors,
                          rng: np.random.Generator) -> np.ndarray:
    """Objects set down while their hand hid them, decided when the hand lifts away.

    A held object in a tracked hand (``in_tracked_hand (M,)``, undetected) that rested on a support
    out of view (:func:`resting_place`: ``rest_at (K, M, 3)``, ``rest_t (K, M)`` finite), and whose
    hand now carries it (``hand_z (M,)`` m, the height the hand puts it at: NaN without a hand) more
    than ``carry_distance`` above that place, when it was not at the last update (``before_z (K, M)``),
    was let go there with probability ``put_down_touched`` (``ModePriors``: a person who lowers a cup
    onto a table and lifts the hand has mostly left it there). A prior draw: no weight. Returns the
    entries let go ``(K, M)`` bool; one uniform draw per entry when there is a candidate."""
    rise = priors.carry_distance
    with np.errstate(invalid="ignore"):
        lifted = (hand_z[None, :] - rest_at[..., 2] > rise) & (before_z - rest_at[..., 2] <= rise)
    cand = ((modes == HELD) & np.isfinite(rest_t) & lifted
            & np.asarray(in_tracked_hand, dtype=bool)[None, :])
    if not np.any(cand):
        return cand
    return cand & (rng.random(modes.shape) < priors.put_down_touched)


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
    return (modes == HELD) & _pushed(holds, lift) & rose & np.asarray(in_tracked_hand, dtype=bool)[None, :]


def _pushed(holds: np.ndarray, lift: float) -> np.ndarray:
    """``(K, M)`` bool: held episodes (``holds (K, M, 6)``, with a Pick time) that never lifted their
    object more than ``lift`` (m): pushed or slid along its support."""
    return ~lifted(holds, lift) & np.isfinite(holds[..., PICK_T])


def let_go_where_rested(entries: np.ndarray, state, poses: np.ndarray, vel: np.ndarray, modes: np.ndarray,
                        codes: np.ndarray) -> np.ndarray:
    """Let go, in place, the ``entries (K, M)`` set down out of view (:func:`set_down_behind_cover`)
    where and when they last rested (``state.rest_at``, ``state.rest_t``), at rest, a Place. Returns
    when each was let go ``(K, M)`` (s; NaN elsewhere)."""
    modes[entries] = FREE
    codes[entries] = PLACE
    poses[entries, :3] = state.rest_at[entries]
    vel[entries] = 0.0
    return np.where(entries, state.rest_t, np.nan)


PUSH_END_SIGMAS = 3.0
"""A pushed object's hand has risen off it when it rose more than ``push_lift`` plus this many
standard deviations of the difference of two tracked hand heights (``HandConfig.measurement_std``
each): a hand tracked to 1 cm jitters by 2 cm between two updates, and a push must not end on that."""

COVER_DROP = 0.10
"""m: an object let go behind cover where it was lowest (put down: ``ModePriors.put_down_hidden``)
whose bottom was more than this above what is under it there was dropped (a Release), else put down
(a Place): a hand's width, set by hand, not fitted. Not the 2 cm of ``push_lift``: the particle
knows that height only through the hand's track and the object's offset to it at its last detection
(a cup put down behind a screen is a few centimetres above the table at its particles' lowest
points; a ball let go over a bin's rim, well above what is under it)."""


def let_go_behind_cover(cover: np.ndarray, state, poses: np.ndarray, vel: np.ndarray, modes: np.ndarray,
                        codes: np.ndarray, put_down: float, rng: np.random.Generator) -> np.ndarray:
    """Let go, in place, the entries ``cover (K, M)`` (:func:`release_behind_cover`) where their hand
    hid them, at rest: with probability ``put_down`` (``ModePriors.put_down_hidden``) put down where
    they were lowest (``state.down_at``, a Place), else dropped at the uniform sample of where they
    were (``state.hidden_at``, a Release); ``poses (K, M, 7)``, ``vel (K, M, 6)``, ``modes`` and
    ``codes (K, M)`` are updated. One uniform draw per entry when there is such an entry.
    Returns when each was let go ``(K, M)`` (s; NaN elsewhere)."""
    if not np.any(cover):
        return np.full(cover.shape, np.nan)
    down = cover & (rng.random(cover.shape) < put_down)  # (a covered entry was hidden: it has both places)
    modes[cover] = FREE
    codes[cover] = np.where(down[cover], PLACE, RELEASE)
    poses[cover, :3] = np.where(down[cover][:, None], state.down_at[cover], state.hidden_at[cover])
    vel[cover] = 0.0
    return np.where(cover, np.where(down, state.down_t, state.hidden_t), np.nan)


def let_go_out_of_view(state, poses: np.ndarray, vel: np.ndarray, modes: np.ndarray, codes: np.ndarray,
                       frame: Frame, memory: PerceptionMemory, following: np.ndarray, perceived: np.ndarray,
                       detected: np.ndarray, priors: ModePriors, noise: NoiseConfig,
                       rng: np.random.Generator, lift: float = 0.02, hand_std: float = 0.0,
                       round_objects: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Held objects in a tracked hand (``following (M,)``) let go out of view, in place on ``poses
    (K, M, 7)``, ``vel (K, M, 6)``, ``modes`` and ``codes (K, M)``: those the hand shows in view
    without (:func:`release_behind_cover`, :func:`let_go_behind_cover`), and those set down where they
    rested, the hand lifting away (:func:`set_down_behind_cover`, :func:`let_go_where_rested`), and
    those pushed along their support whose hand has risen off them (:func:`pushes_ended`, ``lift``
    m beyond the noise of a tracked hand's height, ``hand_std`` m), and those of ``round_objects
    (M,)`` (spheres and cylinders, whose contact with a hand is round; None: none) the hand pushing
    them has slid past (:func:`slide_around_hand`, with each particle's grip, :func:`push_grips`; a
    box pushed on a face is dragged along); none of these in the paper's mode, ``hand_occlusion`` 1. Returns when each entry was let go ``(K, M)``
    (s; NaN for the others: the entries let go are the finite ones), the proposal's log-weight
    factors ``(K,)`` and the grips ``(K, M)`` after the update (``state.push_grip`` with those
    detected forgotten and those of pushes now out of view drawn)."""
    cover, proposal = release_behind_cover(modes, state.unseen_in_view, state.hidden_n, following & ~perceived,
                                           priors, noise, rng)
    when = let_go_behind_cover(cover, state, poses, vel, modes, codes, priors.put_down_hidden, rng)
    unseen = following & ~detected
    grip = state.push_grip.copy()
    grip[:, np.asarray(detected, dtype=bool)] = np.nan
    if noise.hand_occlusion >= 1.0 or not np.any(unseen):
        return when, proposal, grip
    hand_z = memory.hand_heights(frame, unseen)
    set_down = set_down_behind_cover(modes, state.rest_at, state.rest_t, state.poses[..., 2], hand_z, unseen,
                                     priors, rng)
    set_down &= ~_pushed(state.holds, lift)  # never lifted: not set down, its push ends (below)
    if np.any(set_down):
        when = np.where(set_down, let_go_where_rested(set_down, state, poses, vel, modes, codes), when)
    # the hand's rise since the object was last seen: both heights in the tracker's frame (where
    # the hand would carry it now, where it was seen), so that its height bias cancels
    ended = pushes_ended(modes, state.holds, memory.last_pose[:, 2], hand_z, unseen,
                         lift + PUSH_END_SIGMAS * math.sqrt(2.0) * hand_std)
    if np.any(ended):  # left where the push took it, at rest: the episode ends as a Push
        modes[ended] = FREE
        codes[ended] = PLACE
        vel[ended] = 0.0
        when = np.where(ended, frame.t, when)
    slides = unseen & (np.zeros_like(unseen) if round_objects is None else np.asarray(round_objects, dtype=bool))
    pushed = (modes == HELD) & _pushed(state.holds, lift) & slides[None, :]
    grip = push_grips(grip, pushed, detected, rng)
    noise_travel = PUSH_END_SIGMAS * math.sqrt(2.0) * hand_std
    for m in np.flatnonzero(pushed.any(axis=0)):
        rows = np.flatnonzero(pushed[:, m])
        travel = memory.hand_position(memory.hold_hand[m]) - memory.hold_hand_position[m]
        _, lost, at_loss = slide_around_hand(memory.hold_offset[m] + state.hold_error[rows, m], travel,
                                             grip[rows, m], noise_travel)
        if np.any(lost):  # the hand went past it (or away): it stays where it slid off, at rest, a Push
            k = rows[lost]
            slid = np.isfinite(at_loss[lost, 0])
            poses[k[slid], m, :2] = memory.hold_hand_position[m, :2] + at_loss[lost][slid, :2]
            modes[k, m] = FREE
            codes[k, m] = PLACE
            vel[k, m] = 0.0
            when[k, m] = frame.t
    return when, proposal, grip


def dropped_behind_cover(codes: np.ndarray, cover: np.ndarray | None, before: np.ndarray, after: np.ndarray,
                         aabbs: np.ndarray, floor: bool) -> np.ndarray:
    """``codes (K, M)`` with the Places of the entries let go behind ``cover`` turned into Releases
    where the object was let go more than :data:`COVER_DROP` above what is under it (a ball let go
    over a bin's rim), from its height ``before`` and ``after (K, M, 7)`` this update's physics and
    the boxes ``aabbs (K, M, 2, 3)`` after it (:func:`~estimator.model.motion.drop_heights`). A new array
    when any changes."""
    kk, mm = np.nonzero(cover & (codes == PLACE)) if cover is not None else ((), ())
    if not len(kk):
        return codes
    fall = drop_heights(aabbs, kk, mm, before[kk, mm, 2] - after[kk, mm, 2], floor)
    codes = codes.copy()
    codes[kk, mm] = np.where(fall > COVER_DROP, RELEASE, PLACE)
    return codes


def places_after_update(state, ev, settled, t: float, rng: np.random.Generator,
                        threshold: float) -> tuple[np.ndarray, ...]:
    """The particles' samples of where their held objects were out of view (:func:`hidden_places`),
    and where they were lowest then (:func:`lowest_hidden_place`), after an update:
    ``(hidden_at, hidden_t, hidden_n, down_at, down_t)``; and where they last rested on a support out
    of view, undetected (:func:`resting_place`): ``(rest_at, rest_t)``. ``state``: the
    :class:`~estimator.state.ParticleState` before the update; ``ev``: its
    :class:`~estimator.model.likelihood.Evidence`; ``settled``: its :class:`~estimator.model.step.Settled`;
    ``threshold``: the visible fraction that counts as in view."""
    s = state
    in_hand = (settled.modes == HELD) & np.asarray(ev.in_tracked_hand, bool)[None, :]
    in_view = (ev.visible >= threshold) & np.asarray(ev.queried, bool)[None, :]
    reset = (settled.modes != HELD) | ev.detected[None, :]
    hidden = in_hand & ~ev.perceived[None, :] & ~in_view
    # an object that still counts as perceived (t_perceived) follows its hand too: set down then
    unseen = in_hand & ~ev.detected[None, :] & ~in_view
    return (hidden_places(s.hidden_at, s.hidden_t, s.hidden_n, settled.poses, hidden, reset, t, rng)
            + lowest_hidden_place(s.down_at, s.down_t, s.hidden_n, settled.poses, hidden, t)
            + resting_place(s.rest_at, s.rest_t, settled.poses, unseen, settled.supported, reset, t))
