"""Following a hand: where each held object goes in this update (its detection, its tracked hand
plus the offset it was last seen at, or a drift), which is the divergence test's target too
(:func:`~estimator.model.holding.held_targets`); an object its episode never lifted (pushed along its
support) follows the hand along the support, not up (:func:`~estimator.model.holding.push_cannot_lift`,
not in the paper's mode)."""
from __future__ import annotations

import numpy as np

from actions.modes import is_held

from ..holding import held_targets, push_cannot_lift
from ..step import Fall
from .base import ArraySpec, Draft, Mechanism


class FollowHands(Mechanism):
    """Fills :attr:`Draft.detections`, :attr:`Draft.target`, :attr:`Draft.target_vel` and
    :attr:`Draft.hold_error`."""

    arrays = {"hold_error": ArraySpec((3,))}
    """``hold_error (K, M, 3)`` m: how far a held, undetected object following a tracked hand is from the
    hand plus its offset at the last detection (:func:`estimator.worlds.held.hand_offset_walk`)."""

    def commit(self, state, p, w, rng) -> dict:
        return {"hold_error": p.move.hold_error}

    def __init__(self, model, moving: bool = True):
        super().__init__(model)
        self.moving = moving
        """Whether objects are teleported in motion (:class:`~estimator.model.mechanisms.teleport.Teleports`):
        a held object's target then carries on at its perceived velocity."""

    def target(self, u: Draft) -> None:
        mem, cfg = self.model.memory, self.model.config
        # detected in an earlier frame of the update only: moved on with its tracked hand (if some
        # particle holds it, or it is seen moving), or, seen moving, at its velocity
        stale = mem.stale_in_hand(u.frame, is_held(u.modes).any(axis=0)) & u.detected
        u.detections = mem.detections_now(stale, u.t, u.detected if self.moving else None)
        u.target, u.target_vel, u.hold_error = self.held_targets(
            u.frame, u.poses, u.modes, u.detected, u.perceived, u.dt, u.rng, u.state.hold_error, u.tele, u.fall,
            u.detections, stale, u.grip)
        if cfg.noise.hand_occlusion < 1.0:  # as let_go_out_of_view: not in the paper's mode
            push_cannot_lift(u.target, u.target_vel, u.poses, u.modes, u.state.holds, u.detected,
                             cfg.reasoner.push_lift)

    def held_targets(self, frame, poses: np.ndarray, modes: np.ndarray, detected: np.ndarray,
                     perceived: np.ndarray, dt: float, rng: np.random.Generator,
                     hold_error: np.ndarray, teleported: np.ndarray | None = None,
                     falling: Fall | None = None, detections: np.ndarray | None = None,
                     stale: np.ndarray | None = None,
                     grip: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Targets ``(K, M, 7)``, target velocities ``(K, M, 6)`` and hand-offset errors ``(K, M, 3)``
        (:func:`~estimator.model.holding.held_targets`)."""
        cfg = self.model.config
        carried = None
        if self.moving:
            carried = np.zeros(self.model.M, dtype=bool) if teleported is None else teleported
        return held_targets(frame, poses, modes, detected, perceived, dt, rng, hold_error, self.model.memory,
                            cfg.noise, carried, falling, detections, stale, grip, cfg.hands.measurement_std)
