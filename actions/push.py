"""Push: an object moved by an agent along its support, never lifted.

An agent's hand that drags a box along the table moves it without lifting it. The mode model sees a
switch FREE -> HELD (the box diverges from its simulation: an agent moves it) and, when it is let
go on a support, HELD -> FREE; read as Pick and Place, that says the box was picked up. This module
keeps, per particle and object, a *hold record* of each held episode and turns a Place of an object
that was never lifted into a ``Push`` at the time of its Pick, whose Pick is then withdrawn.

The hold record ``(..., M, 6)`` (columns :data:`PICK_T`, :data:`REF_Z`, :data:`SMOOTH_Z`,
:data:`TOP_Z`, :data:`AIRBORNE`, :data:`LET_GO_T`; NaN where unknown):

* ``ref_z`` (m): the object's height the last time it rested free on a support (kept while it is
  held; NaN: it never rested since it became known);
* ``pick_t`` (s): the time of the Pick that started the held episode; NaN: not held, or an
  episode without a Pick whose end is reported (the object was already held when first seen);
  -inf: a *silent* episode, without a Pick, of an object that had been let go before and never
  rested since (a falling object that diverged from its simulation: no one acted), whose end is
  not reported either;
* ``smooth_z`` (m): its height while held, smoothed exponentially (perception noise on a dragged
  object must not look like a lift; NaN: not held);
* ``top_z`` (m): the highest smoothed height of the episode;
* ``airborne``: 1 if the object was held with nothing under it (not supported) at the end of an
  update of the episode, else 0;
* ``let_go_t`` (s): when the object was let go on a support, while that Place waits for physics to
  confirm it (:mod:`actions.episodes`; NaN: none pending). The episode stays open meanwhile.

The object was lifted when ``top_z - ref_z`` exceeds the lift threshold (2 cm by default:
:attr:`~estimator.config.ReasonerConfig.push_lift`) or it was airborne. The lift is measured from
where the object rested in the particle's world before it was held (simulated, so free of the
tracker's height bias, which the held heights have; the threshold must exceed that bias). An object
that switches to HELD without ever having rested (first seen already in a hand, or thrown) was
already held: no Pick (:func:`unrested_picks`); :func:`end_codes` reports the end of an episode
(Place, Release or Push) by the record. The functions work on arrays of any leading shape
(one scene ``(M,)`` or particles ``(K, M)``); they never draw random numbers.
"""
from __future__ import annotations

import numpy as np

from .modes import NO_EVENT, PICK, PLACE, PUSH, RELEASE

PICK_T, REF_Z, SMOOTH_Z, TOP_Z, AIRBORNE, LET_GO_T = range(6)
"""Columns of the hold record."""
HOLD_FIELDS = 6


def empty_holds(shape: tuple[int, ...]) -> np.ndarray:
    """A hold record ``shape + (6,)`` with nothing known (all NaN)."""
    return np.full(tuple(shape) + (HOLD_FIELDS,), np.nan)


def unrested_picks(codes: np.ndarray, holds: np.ndarray) -> np.ndarray:
    """``codes (..., M)`` without the Picks of objects that never rested since they became known
    (``holds (..., M, 6)`` before the update has no ``ref_z``): an object first seen in a hand, in
    the air, was already held; nobody was seen picking it up. A new array."""
    return np.where((np.asarray(codes) == PICK) & np.isnan(holds[..., REF_Z]), NO_EVENT, codes).astype(
        np.asarray(codes).dtype)


def track_holds(holds: np.ndarray, held: np.ndarray, resting: np.ndarray, supported: np.ndarray,
                start_z: np.ndarray, z: np.ndarray, picked: np.ndarray, acted_on: np.ndarray, t: float,
                smoothing: float) -> np.ndarray:
    """The hold record after one update (a new array).

    Args:
        holds: ``(..., M, 6)`` the record before the update.
        held: ``(..., M)`` bool, objects held through this update's physics.
        resting: ``(..., M)`` bool, free objects resting on a support after it (their ``ref_z``
            becomes ``z``, unless their episode is still open).
        supported: ``(..., M)`` bool, objects with something under them after it.
        start_z: ``(..., M)`` m, heights at the start of the update (the reference of an episode
            whose object never rested).
        z: ``(..., M)`` m, heights after the update's physics.
        picked: ``(..., M)`` bool, objects whose switch to HELD in this update is a Pick.
        acted_on: ``(..., M)`` bool, objects that had an event before this update.
        t: the Pick's time (s; a number or an array that broadcasts against ``picked``).
        smoothing: weight in (0, 1] of the new height in the smoothed height (1: no smoothing).

    Held objects without an open episode start one (``pick_t`` = ``t`` if ``picked``, else -inf
    (silent) if ``acted_on``, else NaN; the smoothed and top heights start at ``ref_z``, or at
    ``start_z`` for an object that never rested); every held object's smoothed height moves
    towards ``z`` by ``smoothing``, ``top_z`` follows the highest and ``airborne`` is set when it is
    not ``supported``. :func:`end_holds` closes the episodes of objects let go.
    """
    out = np.array(holds, dtype=float, copy=True)
    held = np.asarray(held, dtype=bool)
    z = np.asarray(z, dtype=float)
    out[..., REF_Z] = np.where(resting & ~held & np.isnan(out[..., SMOOTH_Z]), z, out[..., REF_Z])
    new = held & np.isnan(out[..., SMOOTH_Z])
    ref = np.where(np.isnan(out[..., REF_Z]), start_z, out[..., REF_Z])
    first = np.where(picked, t, np.where(acted_on, -np.inf, np.nan))
    out[..., PICK_T] = np.where(new, first, out[..., PICK_T])
    for col in (SMOOTH_Z, TOP_Z):
        out[..., col] = np.where(new, ref, out[..., col])
    out[..., AIRBORNE] = np.where(new, 0.0, out[..., AIRBORNE])
    smooth = out[..., SMOOTH_Z] + smoothing * (z - out[..., SMOOTH_Z])
    out[..., SMOOTH_Z] = np.where(held, smooth, out[..., SMOOTH_Z])
    out[..., TOP_Z] = np.where(held, np.fmax(out[..., TOP_Z], smooth), out[..., TOP_Z])
    out[..., AIRBORNE] = np.where(held & ~np.asarray(supported, dtype=bool), 1.0, out[..., AIRBORNE])
    return out


def lifted(holds: np.ndarray, lift: float) -> np.ndarray:
    """``(..., M)`` bool: the episode lifted its object more than ``lift`` (m) above where it rested,
    or held it airborne (False without an open episode)."""
    with np.errstate(invalid="ignore"):
        return ((holds[..., TOP_Z] - holds[..., REF_Z]) > lift) | (holds[..., AIRBORNE] > 0)


def end_codes(codes: np.ndarray, holds: np.ndarray, lift: float) -> tuple[np.ndarray, np.ndarray]:
    """The events that end held episodes, by their record: a silent episode's Place or Release is
    no event; the Place of an object never lifted in an episode that began with a Pick is a Push.

    Args:
        codes: ``(..., M)`` event codes of an update (:mod:`actions.modes`).
        holds: ``(..., M, 6)`` the hold record of the episodes these codes end.
        lift: m, the lift threshold.

    Returns:
        The new codes (a copy) and ``push_t (..., M)``: the Push's time (the episode's Pick time, s)
        where the code is now :data:`PUSH`, NaN elsewhere.
    """
    codes = np.array(codes, copy=True)
    pick_t = holds[..., PICK_T]
    codes[((codes == PLACE) | (codes == RELEASE)) & (pick_t == -np.inf)] = NO_EVENT
    push = (codes == PLACE) & ~lifted(holds, lift) & np.isfinite(pick_t)
    codes[push] = PUSH
    return codes, np.where(push, pick_t, np.nan)


def end_holds(holds: np.ndarray, open_: np.ndarray) -> np.ndarray:
    """The record with the episodes of the objects not ``open_ (..., M)`` (held, or let go pending
    confirmation, at the end of the update) closed: every column but ``ref_z`` NaN. A new array."""
    keep = np.asarray(open_, dtype=bool)[..., None] | (np.arange(HOLD_FIELDS) == REF_Z)
    return np.where(keep, holds, np.nan)


def withdraw_picks(pick_t: np.ndarray, push_t: np.ndarray) -> np.ndarray:
    """Latest Pick times ``(..., M)`` (s, -inf: none) with the Picks that became Pushes withdrawn:
    -inf where ``push_t (..., M)`` (NaN: no Push) equals the Pick time. A new array."""
    with np.errstate(invalid="ignore"):
        return np.where(pick_t == push_t, -np.inf, pick_t)


def late_picks(codes: np.ndarray, times: np.ndarray, holds: np.ndarray, held: np.ndarray, onset: np.ndarray,
               quiet: np.ndarray, since: float, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Picks of episodes that began without one because their object was still seen at rest, dated
    when it was then seen to start moving.

    A particle can take an object in hand an update or two before the object's detections leave
    where it rested by more than the tracker's noise (the particle weighs every detection; the
    perception memory calls the object moved only beyond the noise,
    :meth:`~estimator.model.perception_memory.PerceptionMemory.onset`); that switch is silent (a still
    object was moved by no one). Once the object is seen to have started moving, the episode's Pick
    is that start.

    Args:
        codes: ``(..., M)`` int8 event codes of the update.
        times: ``(..., M)`` s, when each event happened (NaN: at ``t``).
        holds: ``(..., M, 6)`` the hold record after the update.
        held: ``(..., M)`` bool, objects held after the update.
        onset: ``(M,)`` s, when each object was seen to start moving (NaN: still).
        quiet: ``(..., M)`` bool, episodes silent for another reason (an object carried in or on a
            held one, out of reach of every tracked hand, or that had an event before: its silent
            episode may be an object let go and never at rest since).
        since: s, the earliest start that still dates a Pick (the event window); ``t``: now (s).

    Only episodes without a Pick (``pick_t`` NaN or -inf) of objects that rested before (``ref_z``
    known) get one; new arrays are returned (the same ones when none does).
    """
    pick_t = holds[..., PICK_T]
    start = np.broadcast_to(np.asarray(onset, dtype=float), pick_t.shape)
    with np.errstate(invalid="ignore"):
        late = (np.asarray(held, dtype=bool) & ~np.isfinite(pick_t) & np.isfinite(holds[..., SMOOTH_Z])
                & np.isfinite(holds[..., REF_Z]) & (start >= since) & (start <= t)
                & ~np.asarray(quiet, dtype=bool) & (np.asarray(codes) == NO_EVENT))
    if not np.any(late):
        return codes, times, holds
    holds = np.array(holds, dtype=float, copy=True)
    holds[..., PICK_T] = np.where(late, start, pick_t)
    return (np.where(late, PICK, codes).astype(np.asarray(codes).dtype), np.where(late, start, times), holds)
