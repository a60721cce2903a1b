"""Time-stamped Pick / Place / Release / Push events from (possibly weighted) mode switches."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import EVENT_NAMES, PICK, PUSH
from .push import withdraw_picks

N_ACTIONS = len(EVENT_NAMES)
"""Columns of an event-time array ``(..., M, N_ACTIONS)``: Pick, Place, Release, Push."""


@dataclass(frozen=True)
class EventRecord:
    """An inferred action: ``action`` ("Pick", "Place", "Release", "Push") on ``subject`` at time
    ``t`` (seconds) with probability ``p``."""

    t: float
    action: str
    subject: str
    p: float

    def to_json(self) -> dict:
        return {"t": round(self.t, 6), "action": self.action, "subject": self.subject,
                "p": round(float(self.p), 4)}


def record_event_times(event_t: np.ndarray, codes: np.ndarray, t: float, times: np.ndarray | None = None,
                       push_decided: np.ndarray | None = None) -> None:
    """Remember, in place, the switches ``codes`` ``(..., M)`` decided at time ``t`` (s).

    ``event_t`` ``(..., M, 4)`` holds, per particle and object, the time of the latest Pick, Place,
    Release and Push (columns in :data:`~actions.modes.EVENT_NAMES` order; -inf when none). Being
    part of the particle state, it is resampled with the particles, so that evidence arriving after a
    switch raises the probability of the event itself.

    ``times (..., M)`` (s; NaN, or None for all: ``t``) is when each switch happened, if earlier than
    when it was decided: a Pick's is when the object started moving, a Push's that of the Pick of
    its episode (:func:`actions.push.end_codes`). A Push withdraws that Pick (its time set to -inf)
    and ``push_decided (..., M)`` (s), when given, gets ``t``, from which :func:`recent_events`
    counts the Push as recent.
    """
    when = np.full(codes.shape, float(t)) if times is None else np.where(np.isnan(times), t, times)
    for code in EVENT_NAMES:
        if code != PUSH:
            sel = codes == code
            event_t[..., code - 1][sel] = when[sel]
    pushed = codes == PUSH
    if not np.any(pushed):
        return
    event_t[..., PICK - 1] = np.where(pushed, withdraw_picks(event_t[..., PICK - 1], when), event_t[..., PICK - 1])
    event_t[..., PUSH - 1][pushed] = when[pushed]
    if push_decided is not None:
        push_decided[pushed] = t


def recent_events(event_t: np.ndarray, weights: np.ndarray, t: float, window: float, object_ids,
                  threshold: float = 0.0, push_decided: np.ndarray | None = None) -> list[EventRecord]:
    """Events that happened within ``window`` seconds before ``t``, with their probabilities.

    Args:
        event_t: ``(K, M, 4)`` latest event times per particle (see :func:`record_event_times`).
        weights: ``(K,)`` normalised particle weights.
        t: now (s); window: how far back (s).
        object_ids: the M object ids.
        threshold: only events with probability above it are returned.
        push_decided: ``(K, M)`` when each particle's latest Push was decided (s; the let-go): a
            Push counts as recent while its decision is, whenever the push began (None: by its time).

    Returns:
        Per object and action with probability p (the weight of the particles that made that switch
        within the window) above ``threshold``: the p-weighted mean time of the switch and p.
    """
    since = t - window - 1e-9
    recent = event_t >= since  # (K, M, 4); -inf never counts
    if push_decided is not None:
        recent[..., PUSH - 1] = (push_decided >= since) & np.isfinite(event_t[..., PUSH - 1])
    p = np.tensordot(weights, recent.astype(float), axes=1)  # (M, 4)
    out = []
    for m, oid in enumerate(object_ids):
        for code, name in EVENT_NAMES.items():
            pm = float(p[m, code - 1])
            if pm > threshold:
                sel = recent[:, m, code - 1]
                t_mean = float(weights[sel] @ event_t[sel, m, code - 1]) / pm
                out.append(EventRecord(t_mean, name, oid, min(pm, 1.0)))
    return out
