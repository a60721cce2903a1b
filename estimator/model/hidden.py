"""Where held objects were while their tracked hand kept them out of view, and how they were let go
there (let go behind cover): array functions over K particles and M objects (metres, seconds);
randomness from the ``numpy.random.Generator`` passed in. The mechanism that calls them is
:class:`~estimator.model.mechanisms.cover.LetGoBehindCover`.
"""
from __future__ import annotations

import math

import numpy as np

from actions.modes import FREE, PLACE, RELEASE, ModePriors, is_free, is_held

from ..config import NoiseConfig
from ..observations import Frame
from .holding import PUSH_END_SIGMAS, never_lifted, push_grips, pushes_ended, slide_around_hand
from .motion import drop_heights
from .perception_memory import PerceptionMemory


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
    cand = is_held(modes) & (unseen_in_view == 1) & (hidden_n > 0) & np.asarray(in_tracked_hand, bool)[None, :]
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
    cand = (is_held(modes) & np.isfinite(rest_t) & lifted
            & np.asarray(in_tracked_hand, dtype=bool)[None, :])
    if not np.any(cand):
        return cand
    return cand & (rng.random(modes.shape) < priors.put_down_touched)


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
    set_down &= ~never_lifted(state.holds, lift)  # never lifted: not set down, its push ends (below)
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
    pushed = is_held(modes) & never_lifted(state.holds, lift) & slides[None, :]
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
    :class:`~estimator.model.terms.Evidence`; ``settled``: its :class:`~estimator.model.step.Settled`;
    ``threshold``: the visible fraction that counts as in view."""
    s = state
    in_hand = is_held(settled.modes) & np.asarray(ev.in_tracked_hand, bool)[None, :]
    in_view = (ev.visible >= threshold) & np.asarray(ev.queried, bool)[None, :]
    reset = is_free(settled.modes) | ev.detected[None, :]
    hidden = in_hand & ~ev.perceived[None, :] & ~in_view
    # an object that still counts as perceived (t_perceived) follows its hand too: set down then
    unseen = in_hand & ~ev.detected[None, :] & ~in_view
    return (hidden_places(s.hidden_at, s.hidden_t, s.hidden_n, settled.poses, hidden, reset, t, rng)
            + lowest_hidden_place(s.down_at, s.down_t, s.hidden_n, settled.poses, hidden, t)
            + resting_place(s.rest_at, s.rest_t, settled.poses, unseen, settled.supported, reset, t))
