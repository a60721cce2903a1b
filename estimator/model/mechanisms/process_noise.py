"""Process noise: free objects nobody perceives, not at rest, wander a little in each particle
(:func:`~estimator.model.noise.process_noise`): the worlds' physics is not the world's."""
from __future__ import annotations

import numpy as np

from actions.modes import is_free

from ..noise import process_noise
from .base import Draft, Mechanism


class ProcessNoise(Mechanism):
    """Fills :attr:`Draft.jolted` (the entries moved by more than 2 mm std)."""

    def noise(self, u: Draft) -> None:
        s = u.state
        u.jolted = self.process_noise(u.poses, u.modes, u.perceived, s.supported, u.resting, s.last_motion, u.dt,
                                      u.rng)

    def process_noise(self, poses: np.ndarray, modes: np.ndarray, perceived: np.ndarray, supported: np.ndarray,
                      resting: np.ndarray, last_motion: np.ndarray, dt: float,
                      rng: np.random.Generator) -> np.ndarray:
        """Process noise, in place on ``poses (K, M, 7)``, on the free, unperceived, known dynamic
        objects that are not ``resting (K, M)`` (on a support and slower than ``rest_speed``: a
        resting object does not wander, and, untouched, sleeps in its world). Returns the objects
        moved by more than 2 mm std ``(K, M)``."""
        model = self.model
        free_unseen = is_free(modes) & (~perceived & model.dynamic & model.known)[None, :] & ~resting
        return process_noise(poses, free_unseen, supported, last_motion, dt, model.config.noise, rng)
