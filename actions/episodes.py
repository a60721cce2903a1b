"""The events of one update: mode switches read through each object's held episode.

A scene model's update switches modes three times per particle and object: held objects not
perceived may be let go before physics (``release_codes``), physics switches diverging free objects
to HELD (``modes_before -> modes_physics``), and the Place / Release rules let held objects go after
it (``modes_physics -> modes_after``). Read one by one (:func:`~actions.modes.switch_events`) they are
Pick, Place and Release; read through the hold record (:mod:`actions.push`) they become what the
person did:

* a Pick of an object that never rested since it became known is none (it was already held); so
  is the Pick of an object carried in or on a held one (a ball seen in a carried crate), whose
  episode is silent: its end is no event either;
* a Place waits for physics: the object let go on a support must rest where it was let go. While
  it waits (at most ``wait`` seconds) the episode stays open. If it is held again (it diverged
  from its simulation: the hand still had it), the Place was not one and the episode goes on, with
  no new Pick. If it came to rest more than ``lift`` below where it is seen now (``seen_z``: it
  is held above its support, not put down), it is held again, with no event. If it is not seen
  and came to rest more than ``lift`` below the height it was held at, it was dropped: a Release.
  Otherwise the Place is confirmed. Either is dated when it was let go;
* a confirmed Place of an object never lifted since its Pick is a Push at the Pick's time
  (:func:`~actions.push.end_codes`), and the end of a silent episode is no event;
* an object free at the start of an update that physics switched to HELD and the Release rule let
  go in the same update (it diverged from its simulation because it fell: a ball rolling off an
  edge) was never held: neither a Pick nor a Release;
* a held object let fall as it rolled off its support's edge (``rolled_off``: seen rolling along
  it, no hand near) had left the hand on the support: its episode was a push, a Push at the Pick's
  time if it was never lifted (else the Release stands).

Arrays are ``(..., M)`` (one scene or ``(K, M)`` particles); heights in metres, times in seconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import HELD, NO_EVENT, PICK, PLACE, PUSH, RELEASE, is_free, is_held, merge_events, switch_events
from .push import LET_GO_T, PICK_T, REF_Z, SMOOTH_Z, end_codes, end_holds, lifted, track_holds, unrested_picks


@dataclass(frozen=True)
class EpisodeRule:
    """``lift`` (m): an object raised more than this above where it rested was lifted (else a put-down
    is a Push), and one that falls more than this once let go had not been put down; ``smoothing``:
    weight of the newest height in the smoothed held height; ``wait`` (s): a Place is confirmed at the
    latest this long after the let-go; ``rest_speed`` (m/s): a free object on a support slower than
    this rests (what the caller's ``resting`` should mean)."""

    lift: float = 0.02
    smoothing: float = 0.3
    wait: float = 0.8
    rest_speed: float = 0.05

    def __post_init__(self):
        if not (self.lift > 0 and 0 < self.smoothing <= 1 and self.wait >= 0 and self.rest_speed > 0):
            raise ValueError("EpisodeRule needs lift > 0, smoothing in (0, 1], wait >= 0 and rest_speed > 0, "
                             f"got {self}")


@dataclass(frozen=True)
class UpdateEvents:
    """The result of :func:`update_events`: ``codes (..., M)`` int8 event codes, ``times (..., M)``
    (s, when each happened if before the update; NaN: at it), ``holds (..., M, 6)`` the record after
    the update and ``modes (..., M)`` int8 the modes after it (objects that fell when let go are held
    again)."""

    codes: np.ndarray
    times: np.ndarray
    holds: np.ndarray
    modes: np.ndarray


def carried(is_in: np.ndarray, on_top: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """``(..., M)`` bool: objects in or on top of an object that is HELD in ``modes (..., M)``, by the
    relations ``is_in (..., M, M)`` and ``on_top (..., M, M + 1)`` (its last column, the floor, is
    never held)."""
    m = is_in.shape[-1]
    held = is_held(modes)[..., None, :]
    return ((np.asarray(is_in, dtype=bool) | np.asarray(on_top, dtype=bool)[..., :m]) & held).any(axis=-1)


@dataclass(frozen=True)
class Switches:
    """What one update did to the objects of each particle (arrays ``(..., M)``), as
    :func:`update_events` reads it:

    * ``modes_before``, ``modes_physics``, ``modes_after`` int8: the modes handed to physics (after
      the releases of unperceived objects), after physics, and after the Place / Release rules;
    * ``release_codes``: codes of the releases before physics (final: their objects were not
      perceived; the record still judges them);
    * ``supported`` / ``resting`` bool, after physics: something under it / and slower than
      ``EpisodeRule.rest_speed``;
    * ``start_z``, ``z``: heights (m) before and after physics; ``seen_z``: where the object is seen in
      this update (NaN: not detected);
    * ``pick_t``: when a Pick now began (s; the object started moving);
    * ``let_go_t``: when a let-go on a support now happened (s; None: at the update's time; the Place
      rule fires once the object has been at rest a while), not before the episode's Pick; the wait
      counts from it;
    * ``release_t``: when the Releases (and Places) of ``release_codes`` happened (s; NaN, or None
      for all: at the update's time; an object let go out of view earlier);
    * ``rolled_off`` bool: objects seen rolling along their support at the last update and falling
      off it in this one with no hand near (None: none).
    """

    modes_before: np.ndarray
    modes_physics: np.ndarray
    modes_after: np.ndarray
    release_codes: np.ndarray
    supported: np.ndarray
    resting: np.ndarray
    start_z: np.ndarray
    z: np.ndarray
    seen_z: np.ndarray
    pick_t: np.ndarray
    let_go_t: float | None = None
    release_t: np.ndarray | None = None
    rolled_off: np.ndarray | None = None


def update_events(holds: np.ndarray, acted_on: np.ndarray, carried: np.ndarray, s: Switches, t: float,
                  rule: EpisodeRule = EpisodeRule()) -> UpdateEvents:
    """The events of one update at time ``t`` (see the module docstring).

    Args:
        holds: ``(..., M, 6)`` the hold record before the update.
        acted_on: ``(..., M)`` bool, objects that had an event before the update.
        carried: ``(..., M)`` bool, objects in or on an object held through this update.
        s: what the update did (:class:`Switches`).
        rule: the episode rule's thresholds.
    """
    modes_before, modes_physics, modes_after, release_codes = s.modes_before, s.modes_physics, s.modes_after, \
        s.release_codes
    supported, resting, start_z, z, seen_z, pick_t = s.supported, s.resting, s.start_z, s.z, s.seen_z, s.pick_t
    let_go_t, release_t, rolled_off = s.let_go_t, s.release_t, s.rolled_off
    held = is_held(modes_physics)
    record = holds  # before this update (its fall off an edge is no lift)
    let_go = holds[..., LET_GO_T]
    pending = np.isfinite(let_go)
    if not (held.any() or pending.any() or np.any(release_codes)):  # nothing held, let go or picked
        out = holds.copy()
        out[..., REF_Z] = np.where(resting & np.isnan(holds[..., SMOOTH_Z]), z, holds[..., REF_Z])
        return UpdateEvents(np.zeros(held.shape, np.int8), np.full(held.shape, np.nan), out,
                            np.asarray(modes_after).copy())
    again = pending & held  # held again: that Place was none, the same episode goes on
    picks = unrested_picks(switch_events(modes_before, modes_physics, supported), holds)
    picks = np.where(again | carried, NO_EVENT, picks).astype(picks.dtype)
    waiting = pending & ~held
    with np.errstate(invalid="ignore"):
        fell = waiting & resting & (seen_z - z > rule.lift)
        dropped = waiting & resting & np.isnan(seen_z) & (holds[..., SMOOTH_Z] - z > rule.lift)
    confirmed = waiting & ~fell & (resting | (t - let_go >= rule.wait - 1e-9))
    modes = np.where(fell, HELD, modes_after).astype(np.asarray(modes_after).dtype)
    puts = switch_events(modes_physics, modes_after, supported)
    flash = is_free(modes_before) & held & (puts == RELEASE)  # held and let fall at once
    puts = np.where(flash, NO_EVENT, puts).astype(puts.dtype)
    picks = np.where(flash, NO_EVENT, picks).astype(picks.dtype)
    new_let_go = puts == PLACE
    puts = np.where(new_let_go, NO_EVENT, puts).astype(puts.dtype)
    ends = np.where(confirmed, np.where(dropped, RELEASE, PLACE), NO_EVENT).astype(puts.dtype)
    codes = merge_events(release_codes, puts, picks, ends)
    holds = track_holds(holds, held, resting, supported, start_z, z, picks == PICK, acted_on | carried, pick_t,
                        rule.smoothing)
    codes, push_t = end_codes(codes, holds, rule.lift)
    if rolled_off is not None:  # let fall off the edge it rolled to: pushed there, not dropped
        edge = (np.asarray(rolled_off, dtype=bool) & (puts == RELEASE) & (codes == RELEASE)
                & ~lifted(record, rule.lift) & np.isfinite(record[..., PICK_T]))
        codes = np.where(edge, PUSH, codes).astype(codes.dtype)
        push_t = np.where(edge, record[..., PICK_T], push_t)
    times = np.where(codes == PICK, pick_t, np.where(codes == PUSH, push_t,
                                                     np.where(confirmed & (codes == ends), let_go, np.nan)))
    if release_t is not None:  # (a let-go behind cover may be a Place: put down back then)
        rc = np.asarray(release_codes)
        with np.errstate(invalid="ignore"):
            times = np.where((codes == rc) & ((rc == RELEASE) | (rc == PLACE)) & np.isfinite(release_t), release_t,
                             times)
    still_waiting = waiting & ~fell & ~confirmed
    when = t if let_go_t is None else np.fmax(let_go_t, holds[..., PICK_T])
    holds[..., LET_GO_T] = np.where(new_let_go, when, np.where(still_waiting, let_go, np.nan))
    holds = end_holds(holds, is_held(modes) | still_waiting | new_let_go)
    return UpdateEvents(codes, times, holds, modes)
