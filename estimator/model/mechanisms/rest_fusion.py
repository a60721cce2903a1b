"""Fusion at rest: an object seen still, at rest on its support in a particle, takes an ensemble
Kalman step towards its latest detection (:func:`~estimator.model.fusion.ensemble_kalman_step`), so that
the particles of a resting object converge on where it is seen instead of keeping their prior's
spread (``NoiseConfig.fuse_resting``)."""
from __future__ import annotations

import numpy as np

from actions.modes import is_free

from ...resampling import normalise_log_weights
from ...worlds.resting import slow
from ..fusion import ensemble_kalman_step, shift_inconsistent
from ..perception_memory import STILL_EFFECTIVE
from .base import Draft, Mechanism

FUSION_MIN_STEP = 5e-4
"""Ensemble Kalman steps of resting objects shorter than this (m) are not taken: a converged object
stays asleep in its world (:meth:`FusionAtRest.fuse_resting`)."""

SHIFT_SIGNIFICANCE = 3.0
"""A resting object's cloud moves whole to the average of its still detections when its weighted
mean is more than this many standard deviations of the gap from it
(:func:`~estimator.model.fusion.shift_inconsistent`: the cloud's spread along the gap and the
average's standard error, :data:`~estimator.model.perception_memory.STILL_FRAMES`). A narrow cloud
that the detections reject (put at one detection in every particle, or thinned by resampling) is
not moved by the Kalman step, and a gap that the average's own noise explains is not worth a shift
(each wakes the object in every world)."""

FUSION_SETTLED = 1.5e-3
"""A resting object whose particles' weighted mean is within this (m, horizontally) of the average of
its detections while still takes no Kalman step: it has converged (:meth:`FusionAtRest.fuse_resting`)."""


class FusionAtRest(Mechanism):
    """Fills :attr:`Draft.nudged` (the entries moved towards their detection)."""

    def rest(self, u: Draft) -> None:
        seen = u.detected & u.perceived & ~u.tele
        u.nudged = self.fuse_resting(u.poses, u.state.log_weights, u.modes, u.resting, seen, u.rng)
        # a nudged object that was barely moving is set at rest: its world loads it asleep, without
        # waking what it touches (woken, a stack would settle again after every step of the fusion)
        u.vel[u.nudged & slow(u.vel)] = 0.0

    def fuse_resting(self, poses: np.ndarray, log_weights: np.ndarray, modes: np.ndarray, resting: np.ndarray,
                     seen: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """In place on ``poses (K, M, 7)``: the horizontal position of every object ``seen (M,)`` now
        (detected, perceived, not teleported), perceived still (no motion onset since it was last
        at rest) and, in a particle (``log_weights (K,)``), free and ``resting (K, M)``, takes an
        ensemble Kalman step towards its latest detection (the prior variance floored at
        ``fusion_floor_std``, steps under :data:`FUSION_MIN_STEP` not taken); a cloud that the
        average of its still detections rejects (:data:`SHIFT_SIGNIFICANCE`) moves whole there instead.
        Returns the entries moved ``(K, M)`` (no entry when ``fuse_resting`` is off)."""
        model = self.model
        nz, mem, K, M = model.config.noise, model.memory, model.K, model.M
        out = np.zeros((K, M), dtype=bool)
        still = seen & model.dynamic & mem.seen_still
        if not nz.fuse_resting or K < 2 or not np.any(still):
            return out
        idx = np.flatnonzero(still)
        mask = is_free(modes[:, idx]) & resting[:, idx]
        if not np.any(mask):
            return out
        weights, _ = normalise_log_weights(log_weights)
        # converged: the cloud's mean within FUSION_SETTLED of the average still detection, the
        # object is left asleep (a step every update would wake it in every world)
        mean = np.einsum("k,kmd->md", weights, poses[:, idx, :2])
        mask &= (np.linalg.norm(mean - mem.still_position[idx, :2], axis=1) > FUSION_SETTLED)[None, :]
        std = mem.last_std[idx]
        std = np.where(np.isfinite(std), std, max(nz.position_std, 1e-3))
        # a cloud that the still detections reject moves whole to where they average (a Kalman step
        # hardly moves a narrow cloud); the others take a Kalman step
        se = std / np.sqrt(np.minimum(mem.still_count[idx], STILL_EFFECTIVE))
        x, shifted = shift_inconsistent(poses[:, idx, :2], weights, mem.still_position[idx, :2], se, mask,
                                        SHIFT_SIGNIFICANCE)
        new, moved = ensemble_kalman_step(x, weights, mem.last_pose[idx, :2], std, mask & ~shifted, rng,
                                          floor_std=nz.fusion_floor_std, min_step=FUSION_MIN_STEP)
        poses[:, idx, :2] = new
        out[:, idx] = moved | shifted
        return out
