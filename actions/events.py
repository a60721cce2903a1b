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


def events_from_switches(codes: np.ndarray, t: float, object_ids, weights: np.ndarray | None = None,
                         threshold: float = 0.0) -> list[EventRecord]:
    """Event records for one update.

    Args:
        codes: ``(M,)`` or ``(K, M)`` event codes from :func:`~actions.modes.switch_events`.
        t: time of the update (s).
        object_ids: the M object ids.
        weights: ``(K,)`` normalised particle weights (required for ``(K, M)`` codes).
        threshold: only events with probability above it are returned.

    Returns:
        One record per (object, action) whose probability (the weight of the particles that made that
        switch) exceeds ``threshold``, in object order then action order.
    """
    codes = np.asarray(codes)
    if codes.ndim == 1:
        codes = codes[None, :]
        weights = np.ones(1)
    if weights is None or len(weights) != codes.shape[0]:
        raise ValueError("weights of shape (K,) are required for (K, M) event codes")
    out = []
    for m, oid in enumerate(object_ids):
        col = codes[:, m]
        for code, name in EVENT_NAMES.items():
            p = float(np.sum(weights[col == code]))
            if p > threshold:
                out.append(EventRecord(float(t), name, oid, min(p, 1.0)))
    return out
