"""Time-stamped Pick / Place / Release events from (possibly weighted) mode switches."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import EVENT_NAMES


@dataclass(frozen=True)
class EventRecord:
    """An inferred action: ``action`` ("Pick", "Place", "Release") on ``subject`` at time ``t``
    (seconds) with probability ``p``."""

    t: float
    action: str
    subject: str
    p: float

    def to_json(self) -> dict:
        return {"t": round(self.t, 6), "action": self.action, "subject": self.subject,
                "p": round(float(self.p), 4)}


def record_event_times(event_t: np.ndarray, codes: np.ndarray, t: float) -> None:
    """Remember, in place, the time ``t`` of the switches ``codes`` ``(..., M)``.

    ``event_t`` ``(..., M, 3)`` holds, per particle and object, the time of the latest Pick, Place
    and Release (columns in :data:`~actions.modes.EVENT_NAMES` order; -inf when none). Being part of
    the particle state, it is resampled with the particles, so that evidence arriving after a switch
    raises the probability of the event itself.
    """
    for code in EVENT_NAMES:
        event_t[..., code - 1][codes == code] = t


def recent_events(event_t: np.ndarray, weights: np.ndarray, t: float, window: float, object_ids,
                  threshold: float = 0.0) -> list[EventRecord]:
    """Events that happened within ``window`` seconds before ``t``, with their probabilities.

    Args:
        event_t: ``(K, M, 3)`` latest event times per particle (see :func:`record_event_times`).
        weights: ``(K,)`` normalised particle weights.
        t: now (s); window: how far back (s).
        object_ids: the M object ids.
        threshold: only events with probability above it are returned.

    Returns:
        Per object and action with probability p (the weight of the particles that made that switch
        within the window) above ``threshold``: the p-weighted mean time of the switch and p.
    """
    recent = event_t >= t - window - 1e-9  # (K, M, 3); -inf never counts
    p = np.tensordot(weights, recent.astype(float), axes=1)  # (M, 3)
    out = []
    for m, oid in enumerate(object_ids):
        for code, name in EVENT_NAMES.items():
            pm = float(p[m, code - 1])
            if pm > threshold:
                sel = recent[:, m, code - 1]
                t_mean = float(weights[sel] @ event_t[sel, m, code - 1]) / pm
                out.append(EventRecord(t_mean, name, oid, min(pm, 1.0)))
    return out
