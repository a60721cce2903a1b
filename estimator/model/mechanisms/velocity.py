"""Velocity evidence: an object seen moving along its support is weighed on how fast each particle's
physics had it moving (its friction included) against the velocity now perceived
(:class:`VelocityTerm`), and the model tracks how far the particles are from that velocity as a
whole (:attr:`~estimator.model.SceneModel.surprise`, :meth:`VelocityEvidence.after_weighing`). Part
of the full model (``moving_teleports``, with a ``velocity_slack`` above 0)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.modes import is_free

from ..likelihood import velocity_log_likelihood
from ..motion import rolled_along
from ..weighing import mean_innovation
from .base import Draft, Mechanism


class VelocityEvidence(Mechanism):
    """Keeps, for the update being weighed, :attr:`checked`: ``(mask (K, M), predicted (K, M, 2),
    seen (M, 2), seen_std (M,))`` (None: nothing checked). ``mask``: objects seen moving along their
    support at this update and the last, free in the particle at the last one, whose horizontal
    velocity then, ``predicted`` (m/s, what the particle's physics had made of it, friction
    included), is weighed against the one perceived now, ``seen``, with standard deviation
    ``seen_std`` (the line fitted through the detections over 0.2 s, whose slope is the velocity
    about 0.1 s back: where the particle's is). A teleport in motion gives every particle the
    perceived velocity again at every update, so the position alone says little about how fast the
    object slows down; this does. Only particles in which the object is still free after physics
    are weighed."""

    def __init__(self, model):
        super().__init__(model)
        self.checked: tuple | None = None

    def terms(self) -> tuple:
        nz = self.model.config.noise
        return (VelocityTerm(self, nz.velocity_slack, nz.outlier_prob),)

    def perceive(self, u: Draft) -> None:
        mem = self.model.memory
        self.checked = None
        along = u.moving & ~u.falling & mem.perceived_prev & rolled_along(mem.previous_tick_velocity())
        if along.any():
            mask = along[None, :] & is_free(u.prev_modes)
            self.checked = (mask, u.state.velocities[..., :2].copy(), mem.perc_vel[:, :2].copy(),
                            mem.velocity_std(self.model.config.noise.position_std))

    def after_weighing(self, ev, log_weights: np.ndarray) -> None:
        """Track, per object, how far the perceived velocity of an object moving on its support is
        from what the particles' physics predicted, in units of its standard deviation, under the new
        weights ``log_weights (K,)``: an exponential average (half of the old, half of the new) of the
        squared mean innovation (the model's ``surprise (M,)``). Calibrated, it stays near 1; a value
        over :data:`~estimator.model.weighing.SURPRISE` says every particle gets the object's motion
        wrong the same way (its friction is outside what the particles hold), and its parameters are
        widened at the next resampling (:func:`~estimator.model.regularisation.regularise`)."""
        model = self.model
        if self.checked is None:
            return
        mask, predicted, seen, seen_std = self.checked
        std = np.sqrt(np.asarray(seen_std, float) ** 2 + model.config.noise.velocity_slack ** 2)
        new = mean_innovation(log_weights, mask & is_free(ev.modes), predicted, seen, std)
        ok = np.isfinite(new)
        model.surprise[ok] = 0.5 * model.surprise[ok] + 0.5 * new[ok]


@dataclass(frozen=True)
class VelocityTerm:
    """The log-weight term of :class:`VelocityEvidence` (``mechanism``): perceived velocities of
    objects moving on their support against what the particles' physics made of their velocity over
    the last update (:func:`~estimator.model.likelihood.velocity_log_likelihood`, only where the
    object is still free in the particle): how fast a rolled ball slows down is its rolling
    friction. ``slack`` (m/s) is added in quadrature to each perceived velocity's standard error
    (the model's own error); zero when nothing was checked."""

    mechanism: VelocityEvidence
    slack: float
    outlier_prob: float

    def __call__(self, ev) -> np.ndarray:
        checked = self.mechanism.checked
        if checked is None:
            return np.zeros(len(ev.poses))
        mask, predicted, seen, seen_std = checked
        std = np.sqrt(np.asarray(seen_std, dtype=float) ** 2 + self.slack ** 2)
        return velocity_log_likelihood(predicted, seen, std, mask & is_free(ev.modes), self.outlier_prob)
