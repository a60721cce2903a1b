"""Velocity evidence: an object seen moving along its support is weighed on how fast each particle's
physics had it moving (its friction included) against the velocity now perceived
(:class:`~estimator.model.terms.VelocityTerm`). Part of the full model (``moving_teleports``, with a
``velocity_slack`` above 0)."""
from __future__ import annotations

from actions.modes import is_free

from ..motion import rolled_along
from ..terms import VelocityTerm
from .base import Draft, Mechanism


class VelocityEvidence(Mechanism):
    """Fills :attr:`Draft.speed_check`: the objects seen moving along their support at this and the
    last update, free in the particle before it, with their velocity in it then and the perceived one."""

    def terms(self) -> tuple:
        nz = self.model.config.noise
        return (VelocityTerm(nz.velocity_slack, nz.outlier_prob),)

    def perceive(self, u: Draft) -> None:
        mem = self.model.memory
        along = u.moving & ~u.falling & mem.perceived_prev & rolled_along(mem.previous_tick_velocity())
        if along.any():
            mask = along[None, :] & is_free(u.prev_modes)
            u.speed_check = (mask, u.state.velocities[..., :2].copy(), mem.perc_vel[:, :2].copy(),
                             mem.velocity_std(self.model.config.noise.position_std))
