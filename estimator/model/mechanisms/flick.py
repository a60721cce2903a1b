"""Let go in motion: an object seen moving along its support, out of reach of every tracked hand,
may have been let go (flicked, thrown along the table) in a share of the particles
(``ModePriors.let_go_moving``, :func:`~estimator.model.motion.let_go_moving`): physics takes it on at its
velocity, a Place."""
from __future__ import annotations

import numpy as np

from actions.modes import FREE, PLACE

from ..motion import let_go_moving
from .base import Draft, Mechanism


class LetGoMoving(Mechanism):
    """Let-goes in motion of the dynamic objects seen in this update that no tracked hand can reach
    (every one of them when no hand is tracked); adds their proposal log-weight factor."""

    def release(self, u: Draft) -> None:
        flicked, weight = self.let_go_moving(u.modes, u.state.supported, u.detected & u.perceived, u.tick_vel, u.far,
                                             u.rng)
        if np.any(flicked):  # let go in motion: physics takes it on at its velocity
            u.modes[flicked] = FREE
            u.release_codes[flicked] = PLACE
        u.proposal = u.proposal + weight

    def let_go_moving(self, modes: np.ndarray, supported: np.ndarray, seen: np.ndarray, tick_vel: np.ndarray,
                      far: np.ndarray | None, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Let-goes in motion ``(K, M)`` bool and their log-weight factors ``(K,)``
        (:func:`~estimator.model.motion.let_go_moving`, at ``ModePriors.let_go_moving``) of the dynamic objects
        ``seen (M,)`` in this update that are ``far (M,)`` from every tracked hand (None: no hand
        tracked, all of them)."""
        model = self.model
        cand = seen & model.dynamic & (np.ones(model.M, bool) if far is None else far)
        return let_go_moving(modes, supported, cand, tick_vel, model.config.priors.let_go_moving, rng)
