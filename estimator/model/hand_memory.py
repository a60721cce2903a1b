"""What the perception memory keeps of the tracked hands: each hand's filtered position, and for each
object the hand nearest to it when it was last detected and its offset to that hand; what follows
from them (where a held object is now, how far its hand has carried it).

:class:`HandsInMemory` is a part of :class:`~estimator.model.perception_memory.PerceptionMemory`
(M objects; metres, seconds); it reads the memory's ``last_pose`` and ``follow_hands``.
"""
from __future__ import annotations

import numpy as np

from ..config_sections import HandConfig
from ..observations import Frame
from .hands import HandFilter, average_offset

HAND_RADIUS = 0.3
"""A tracked hand within this distance (m) of a detected object is taken to be the one holding it."""


class HandsInMemory:
    """The tracked hands in the perception memory: ``hold_hand`` (name of the tracked hand near each
    object when last detected, or None), ``hold_offset (M, 3)`` (object minus raw hand position, m,
    averaged over the frames that showed both, :func:`~estimator.model.hands.average_offset`) and
    ``hold_hand_position (M, 3)`` (that hand's filtered position then, m)."""

    hand_config: HandConfig
    last_pose: np.ndarray
    follow_hands: bool

    def _init_hands(self, M: int) -> None:
        self.hold_hand: list[str | None] = [None] * M
        self.hold_offset = np.zeros((M, 3))
        self._offset_n = np.zeros(M, dtype=int)
        self._offset_t = np.full(M, -np.inf)
        self.hold_hand_position = np.full((M, 3), np.nan)
        self._hands: dict[str, HandFilter] = {}

    def _nearest_hand(self, frame: Frame, m: int) -> None:
        """Remember the tracked hand nearest to object m (within :data:`HAND_RADIUS`) and the
        offset, averaged while the same hand stays nearest (:func:`~estimator.model.hands.average_offset`)."""
        before = self.hold_hand[m]
        self.hold_hand[m] = None
        if not frame.hands:
            return
        names = list(frame.hands)
        hp = np.array([frame.hands[n] for n in names])
        d = np.linalg.norm(hp - self.last_pose[m, :3], axis=1)
        best = int(np.argmin(d))
        if d[best] < HAND_RADIUS:
            name = names[best]
            n = self._offset_n[m] if name == before else 0
            self.hold_offset[m], self._offset_n[m] = average_offset(
                self.hold_offset[m], n, frame.t - self._offset_t[m], self.last_pose[m, :3] - hp[best],
                self.hand_config)
            self._offset_t[m] = frame.t
            self.hold_hand[m] = name
            self.hold_hand_position[m] = self.hand_position(name)

    def hand_position(self, name: str) -> np.ndarray:
        """Position ``(3,)`` m of tracked hand ``name``, filtered (:class:`~estimator.model.hands.HandFilter`;
        NaN if never tracked)."""
        hand = self._hands.get(name)
        return hand.position if hand is not None else np.full(3, np.nan)

    def hand_travel(self) -> np.ndarray:
        """Distance ``(M,)`` (m) the hand that held each object when it was last detected has moved
        since then (filtered positions, :meth:`hand_position`); NaN for objects without one."""
        out = np.full(self.M, np.nan)
        for m, name in enumerate(self.hold_hand):
            if name is not None:
                out[m] = float(np.linalg.norm(self.hand_position(name) - self.hold_hand_position[m]))
        return out

    def following_hand(self, frame: Frame) -> np.ndarray:
        """Objects ``(M,)`` whose hand (when last detected) is tracked in ``frame`` (none when hands
        are not followed)."""
        if not self.follow_hands:
            return np.zeros(self.M, dtype=bool)
        return np.array([h is not None and h in frame.hands for h in self.hold_hand])

    def hand_target(self, frame: Frame, m: int) -> np.ndarray | None:
        """Where object m is, ``(3,)`` m, if it follows its tracked hand in ``frame``: the hand's
        filtered position (:meth:`hand_position`; ``frame`` recorded) plus the object's offset to it;
        else None."""
        hand = self.hold_hand[m]
        if hand is not None and hand in frame.hands and self.follow_hands:
            return self.hand_position(hand) + self.hold_offset[m]
        return None

    def hand_heights(self, frame: Frame, objects: np.ndarray) -> np.ndarray:
        """Height ``(M,)`` (m) at which each of ``objects (M,)`` follows its tracked hand in ``frame``
        (:meth:`hand_target`); NaN for the others and where the hand is not in the frame."""
        out = np.full(self.M, np.nan)
        for m in np.flatnonzero(objects):
            at = self.hand_target(frame, m)
            if at is not None:
                out[m] = at[2]
        return out
