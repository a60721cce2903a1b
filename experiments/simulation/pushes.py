"""Truth ``Push`` events: objects the scripted hand moves along their support without grasping them.

A push *episode* of an object starts at the first simulation step at which the hand touches it
(contact with the hand's sphere, while the hand pushes: ``collide``) and ends :data:`PUSH_GAP`
seconds after the hand last touched it (or when the hand grasps it: that is a Pick, not a push; or
at the end of the run). The episode is a ``Push`` when, over the episode, the object

* moved by more than :data:`PUSH_DISTANCE` horizontally from where it was at the first touch, and
* stayed on its support: its height never rose above, nor fell below, its height at the first
  touch by more than :data:`PUSH_LIFT` (lifted, tipped over or knocked off the table: no Push).

The Push's time is the step at which the object had moved :data:`PUSH_START` from where it was
first touched (when it started moving under the hand). Steps count from 1 at ``t = dt``; positions
are metres in the world frame, z up. Deciding which objects may start an episode (touched by the
hand, not held, not carried inside a container the hand moves) is the simulator's
(:class:`~experiments.simulation.ground_truth.GroundTruth`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PUSH_DISTANCE = 0.02
"""m: an object the hand moved horizontally by more than this, without grasping it, was pushed."""
PUSH_START = 0.005
"""m: a push starts when the object has moved this far from where the hand first touched it."""
PUSH_LIFT = 0.02
"""m: a pushed object stays on its support: its height stays within this of its height at the touch."""
PUSH_GAP = 0.5
"""s: a push episode ends this long after the hand last touched the object."""


@dataclass
class PushEpisode:
    """One object's contact with the hand: ``first_step`` and ``last_contact`` (steps), ``ref (3,)``
    (m, its position at the first touch), ``start_step`` (the step it had moved :data:`PUSH_START`,
    None until then), ``moved`` (m, largest horizontal displacement from ``ref``), ``rise`` / ``drop``
    (m, highest height above and lowest below ``ref``'s, both >= 0)."""

    first_step: int
    last_contact: int
    ref: np.ndarray
    start_step: int | None = None
    moved: float = 0.0
    rise: float = 0.0
    drop: float = 0.0

    def update(self, step: int, position: np.ndarray, touching: bool) -> None:
        """Record the object's ``position (3,)`` (m) at ``step``; ``touching``: the hand touches it."""
        d = np.asarray(position, dtype=float) - self.ref
        horizontal = float(np.hypot(d[0], d[1]))
        self.moved = max(self.moved, horizontal)
        self.rise = max(self.rise, float(d[2]))
        self.drop = max(self.drop, float(-d[2]))
        if self.start_step is None and float(np.linalg.norm(d)) > PUSH_START:
            self.start_step = step
        if touching:
            self.last_contact = step

    def is_push(self) -> bool:
        """Whether the episode was a push (see the module docstring)."""
        return (self.start_step is not None and self.moved > PUSH_DISTANCE and self.rise <= PUSH_LIFT
                and self.drop <= PUSH_LIFT)


class PushTracker:
    """The push episodes of a run. ``gap_steps``: :data:`PUSH_GAP` in simulation steps.

    Each step, :meth:`step` takes the objects the hand touches and the positions of those and of the
    objects whose episode is open, and returns the pushes that ended: ``[(object index, step)]``.
    """

    def __init__(self, gap_steps: int):
        self.gap_steps = int(gap_steps)
        self.active: dict[int, PushEpisode] = {}

    def step(self, step: int, touched: set[int], positions: dict[int, np.ndarray]) -> list[tuple[int, int]]:
        """Advance to ``step``: open episodes for newly ``touched`` objects, record ``positions``
        (``{index: (3,)}``, m; every touched or open object), close the episodes whose last touch is
        more than ``gap_steps`` old. Returns the closed episodes that were pushes, as
        ``(index, start_step)``."""
        for i in touched:
            if i not in self.active:
                self.active[i] = PushEpisode(step, step, np.asarray(positions[i], dtype=float).copy())
        ended = []
        for i, ep in list(self.active.items()):
            ep.update(step, positions[i], i in touched)
            if step - ep.last_contact > self.gap_steps:
                ended.append(i)
        return self._close(ended)

    def cancel(self, index: int) -> None:
        """Forget ``index``'s open episode (the hand grasped it: a Pick, not a push)."""
        self.active.pop(index, None)

    def finish(self) -> list[tuple[int, int]]:
        """Close every open episode (the end of the run); returns the pushes as in :meth:`step`."""
        return self._close(list(self.active))

    def _close(self, indices: list[int]) -> list[tuple[int, int]]:
        out = []
        for i in indices:
            ep = self.active.pop(i)
            if ep.is_push():
                out.append((i, ep.start_step))
        return out
