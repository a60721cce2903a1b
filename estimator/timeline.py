"""The timeline: facts with start and end times, and instantaneous action events.

In the spirit of Underworlds situations: a fact (``isOnTop(cup, table)``, ``isHeld(cup)``...) opens
when its probability reaches ``threshold`` and closes when it falls below; its ``confidence`` is the
mean probability while open. An action enters the timeline when the probability that it happened
within the estimator's event window reaches ``threshold``; its time is the probability-weighted mean
time of the particles' switches, and its probability the highest reached while it stays above.

A Push is known only when the object is let go, unlifted (:mod:`actions.push`), while its Pick
entered the timeline when the object started moving: the Push then *revises* that Pick (same
subject, times within ``merge``): the Pick is replaced by the Push, and does not come back.
"""
from __future__ import annotations

import json
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

    def __init__(self, threshold: float = 0.5, merge: float = 0.3):
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {threshold}")
        self.threshold = threshold
        self.merge = merge
        self.facts: list[dict] = []
        self.events: list[EventRecord] = []
        self._open: dict[tuple, _OpenFact] = {}
        self._open_events: dict[tuple[str, str], int] = {}
        self._revised: dict[str, list[float]] = {}  # subject -> times of Picks revised into Pushes
        self.t_end: float | None = None
        self.kept_since: float | None = None  # set by forget_before: what is older was dropped

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
        """Take this update's windowed event probabilities (see :func:`actions.events.recent_events`);
        returns the events that entered the timeline now.

        An event enters when its probability reaches ``threshold``; while it stays above, later updates
        raise its recorded probability (and refine its time) instead of adding a new event, unless
        the switch time moved on by more than ``merge`` seconds (a new action of the same kind). One
        that drops below and comes back at a time within ``merge`` of an event of the same action
        and subject already recorded is that event (its probability raised), not a second one. A
        new Push takes the place of the Pick of its subject nearest its time, within ``merge`` (the
        Pick it revises); that Pick does not enter again.
        """
        new = []
        seen = set()
        for e in events:
            key = (e.subject, e.action)
            if e.p < self.threshold - 1e-12:
                continue
            seen.add(key)
            idx = self._open_events.get(key)
            if idx is not None and e.t - self.events[idx].t <= self.merge:
                old = self.events[idx]
                if e.p > old.p:
                    self.events[idx] = EventRecord(e.t, e.action, e.subject, e.p)
                continue
            if e.action == "Pick" and any(abs(e.t - r) <= self.merge for r in self._revised.get(e.subject, ())):
                continue  # a Pick already revised into a Push
            same = self._nearest(e.action, e.subject, e.t)
            if same is not None:  # back in the window (a later let-go decided in some particles): the
                if e.p > self.events[same].p:  # same action, already recorded, not a second one
                    self.events[same] = EventRecord(self.events[same].t, e.action, e.subject, e.p)
                self._open_events[key] = same
                continue
            j = self._nearest("Pick", e.subject, e.t) if e.action == "Push" else None  # the Pick it revises
            if j is None:
                self.events.append(e)
                j = len(self.events) - 1
            else:
                self._revised.setdefault(e.subject, []).append(self.events[j].t)
                if self._open_events.get((e.subject, "Pick")) == j:
                    del self._open_events[(e.subject, "Pick")]
                self.events[j] = e
            self._open_events[key] = j
            new.append(e)
        for key in [k for k in self._open_events if k not in seen]:
            del self._open_events[key]
        return new

    def _nearest(self, action: str, subject: str, t: float) -> int | None:
        """Index of the event in :attr:`events` of ``action`` and ``subject`` whose time is nearest
        ``t`` (s), within ``merge`` seconds (None: none)."""
        best, best_dt = None, self.merge + 1e-9
        for i, e in enumerate(self.events):
            if e.action == action and e.subject == subject and abs(e.t - t) <= best_dt:
                best, best_dt = i, abs(e.t - t)
        return best

    def forget_before(self, t: float) -> None:
        """Drop the facts that ended and the events that happened before ``t`` (s), so that a
        timeline kept over an endless stream holds a bounded window (``run --timeline-window``).
        Open facts and events still being refined are kept; :meth:`to_json` then names ``t`` as
        ``kept_since``. Later updates are unaffected as long as ``t`` is more than ``merge`` seconds
        older than the events they refine or revise."""
        keep = [i for i, e in enumerate(self.events) if e.t >= t or i in self._open_events.values()]
        if len(keep) < len(self.events) or any(f["end"] < t for f in self.facts):
            self.kept_since = t if self.kept_since is None else max(self.kept_since, t)
        index = {old: new for new, old in enumerate(keep)}
        self.events = [self.events[i] for i in keep]
        self._open_events = {k: index[i] for k, i in self._open_events.items()}
        self.facts = [f for f in self.facts if f["end"] >= t]
        for subject in list(self._revised):
            times = [r for r in self._revised[subject] if r >= t - self.merge]
            if times:
                self._revised[subject] = times
            else:
                del self._revised[subject]

    @staticmethod
    def _fact(key, f: _OpenFact, end: float | None) -> dict:
        predicate, subject, obj = key
        return {"predicate": predicate, "subject": subject, "object": obj, "start": round(f.start, 6),
                "end": None if end is None else round(end, 6), "confidence": round(f.p_sum / f.n, 4)}

    def to_json(self) -> dict:
        """The timeline document; facts still open have ``end: null``."""
        facts = list(self.facts) + [self._fact(k, f, None) for k, f in self._open.items()]
        facts.sort(key=lambda d: (d["start"], d["predicate"], d["subject"], str(d["object"])))
        doc = {"version": TIMELINE_FORMAT_VERSION, "t_end": self.t_end, "facts": facts,
               "events": [e.to_json() for e in sorted(self.events, key=lambda e: e.t)]}
        if self.kept_since is not None:
            doc["kept_since"] = self.kept_since
        return doc

    def write(self, path: str) -> None:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_json(), fh, indent=1)
            fh.write("\n")
