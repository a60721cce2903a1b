"""The timeline: facts with start and end times, and instantaneous action events.

In the spirit of Underworlds situations: a fact (``isOnTop(cup, table)``, ``isHeld(cup)``...) opens
when its probability reaches ``threshold`` and closes when it falls below; its ``confidence`` is the
mean probability while open. An action enters the timeline when the probability mass of that action
on that object, summed over the updates of the last ``event_window`` seconds, reaches ``threshold``;
its time is the probability-weighted mean time of those updates.
"""
from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass

from actions.events import EventRecord

TIMELINE_FORMAT_VERSION = 1


@dataclass
class _OpenFact:
    start: float
    p_sum: float
    n: int


class Timeline:
    """Accumulates facts and events over a run. ``threshold`` in (0, 1]; ``event_window`` in s."""

    def __init__(self, threshold: float = 0.5, event_window: float = 1.0):
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {threshold}")
        self.threshold = threshold
        self.event_window = event_window
        self.facts: list[dict] = []
        self.events: list[EventRecord] = []
        self._open: dict[tuple, _OpenFact] = {}
        self._pending: dict[tuple[str, str], deque] = {}
        self.t_end: float | None = None

    def observe_facts(self, t: float, probabilities: dict[tuple, float]) -> None:
        """Record fact probabilities at time ``t``. Keys: ``(predicate, subject, object_or_None)``;
        facts absent from the mapping have probability 0."""
        for key, p in probabilities.items():
            if p >= self.threshold:
                f = self._open.get(key)
                if f is None:
                    self._open[key] = _OpenFact(t, p, 1)
                else:
                    f.p_sum += p
                    f.n += 1
        for key in [k for k in self._open if probabilities.get(k, 0.0) < self.threshold]:
            f = self._open.pop(key)
            self.facts.append(self._fact(key, f, t))
        self.t_end = t

    def observe_events(self, t: float, events: list[EventRecord]) -> list[EventRecord]:
        """Add this update's event probabilities; returns the events that entered the timeline now."""
        new = []
        for e in events:
            q = self._pending.setdefault((e.subject, e.action), deque())
            q.append((e.t, e.p))
        for key, q in self._pending.items():
            while q and q[0][0] < t - self.event_window:
                q.popleft()
            mass = sum(p for _, p in q)
            if q and mass >= self.threshold - 1e-12:
                t_mean = sum(ti * p for ti, p in q) / mass
                rec = EventRecord(t_mean, key[1], key[0], min(mass, 1.0))
                self.events.append(rec)
                new.append(rec)
                q.clear()
        return new

    @staticmethod
    def _fact(key, f: _OpenFact, end: float | None) -> dict:
        predicate, subject, obj = key
        return {"predicate": predicate, "subject": subject, "object": obj, "start": round(f.start, 6),
                "end": None if end is None else round(end, 6), "confidence": round(f.p_sum / f.n, 4)}

    def to_json(self) -> dict:
        """The timeline document; facts still open have ``end: null``."""
        facts = list(self.facts) + [self._fact(k, f, None) for k, f in self._open.items()]
        facts.sort(key=lambda d: (d["start"], d["predicate"], d["subject"], str(d["object"])))
        return {"version": TIMELINE_FORMAT_VERSION, "t_end": self.t_end, "facts": facts,
                "events": [e.to_json() for e in sorted(self.events, key=lambda e: e.t)]}

    def write(self, path: str) -> None:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_json(), fh, indent=1)
            fh.write("\n")
