"""Release on loss: a held object that stops being perceived may have been let go, where the camera
could not see it.

Each update, a held object that is not perceived is let go in a share of the particles: the prior
``release_on_loss`` (``ModePriors``) at the update it stops being perceived (``release_on_loss_carried``
or ``release_on_loss_still`` when its hand is tracked, by how far the hand carried it), ``release``
at each update after; with ``moving_teleports`` one seen moving along its support at the last update,
not detected now and in no tracked hand, is let go in every particle, at the velocity of the line
through its detections. The weights then compare the particles that let go with those that kept it.
"""
from __future__ import annotations

import numpy as np

from actions.modes import FREE, ModePriors, is_held, switch_events

from ..holding import stratified_uniforms
from ..motion import rolled_along, velocity_draws
from ..perception_memory import PerceptionMemory
from .base import ArraySpec, Draft, Mechanism


def release_on_loss(modes: np.ndarray, perceived: np.ndarray, supported: np.ndarray, rng: np.random.Generator,
                    memory: PerceptionMemory, priors: ModePriors,
                    tracked: np.ndarray | None = None,
                    left_view: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Releases of held objects that are not perceived (``modes (K, M)`` int8, ``perceived (M,)``),
    or that ``left_view (M,)`` now: seen moving along their support at the last update, not detected
    in this one, with no tracked hand. Those are let go in every particle: with no hand to follow,
    physics is the only model of where they go (a ball flicked behind a box rolls on and stops), not
    the detection carried on at a constant velocity until it stops counting as perceived.

    With probability ``release_on_loss`` when they were perceived at the last update; for the objects
    whose hand is tracked (``tracked (M,)``) ``release_on_loss_carried`` when the hand has moved more
    than ``carry_distance`` since the object was last seen (:meth:`PerceptionMemory.hand_travel`), else
    ``release_on_loss_still``; ``release`` per update after (not while the tracked hand has carried
    the object more than ``carry_distance`` since it was seen). Returns the new modes ``(K, M)`` and
    the event codes of the switches ``(K, M)`` (``supported (K, M)``: Place or Release).

    The draws are stratified over the particles (:func:`stratified_uniforms`): a release of
    probability ``p`` lets go ``K p`` particles give or take one, not a binomial count (at
    ``release_on_loss_carried`` 0.024 and K = 64, 1 or 2 rather than 1.5 +- 1.2): the
    share that let go is what the weights then compare with the particles that kept it."""
    K, M = modes.shape
    new = modes.copy()
    lost = memory.perceived_prev & ~perceived
    u = stratified_uniforms(K, M, rng)
    gone = ~perceived
    on_loss = np.full(M, priors.release_on_loss)
    later = np.full(M, priors.release)
    if tracked is not None and np.any(tracked):
        tracked = np.asarray(tracked, dtype=bool)
        carried = memory.hand_travel() > priors.carry_distance  # NaN (no hand): False
        on_loss[tracked & carried] = priors.release_on_loss_carried
        on_loss[tracked & ~carried] = priors.release_on_loss_still
        later[tracked & carried] = 0.0  # what a moving hand carries, it keeps
    p_rel = np.where(lost, on_loss, later)
    if left_view is not None:  # let go for certain
        left_view = np.asarray(left_view, dtype=bool)
        gone, p_rel = gone | left_view, np.where(left_view, 1.0, p_rel)
    new[is_held(new) & gone[None, :] & (u < p_rel[None, :])] = FREE
    return new, switch_events(modes, new, supported)


class ReleaseOnLoss(Mechanism):
    """Releases of held objects that are not perceived (:func:`release_on_loss`); then, once every
    let-go is decided, the velocities of those that left view moving and of balls let go on a support,
    and when each was let go (:attr:`Draft.let_go`)."""

    arrays = {"let_go_unseen": ArraySpec((), float, -np.inf)}
    """``let_go_unseen (K, M)``: time (s) at which the particle let the object go when it stopped being
    perceived (-inf: never); its fall happened unseen, in the ``t_perceived`` before."""

    def __init__(self, model, left_view: bool = True):
        super().__init__(model)
        self.left_view = left_view
        """Whether an object seen moving along its support when it left view is let go in motion."""
        self._gone_moving: np.ndarray | None = None  # (M,): this update's objects that left view moving

    def commit(self, state, p, w, rng) -> dict:
        return {"let_go_unseen": p.move.let_go_unseen}

    def release(self, u: Draft) -> None:
        mem = self.model.memory
        self._gone_moving = None
        if self.left_view:  # seen moving along at the last update (its last two detections, or the line
            # fitted since it started moving: one noisy pair may read a 0.25 m/s roll as 0.18), not now,
            # no tracked hand
            along = rolled_along(mem.previous_tick_velocity()) | (np.isfinite(mem.moving_since)
                                                                   & rolled_along(mem.perc_vel[:, :3]))
            self._gone_moving = u.perceived & ~u.detected & along & ~u.following
        u.modes, u.release_codes = self.releases(u.prev_modes, u.perceived, u.state.supported, u.rng, u.following,
                                                 self._gone_moving)

    def releases(self, modes: np.ndarray, perceived: np.ndarray, supported: np.ndarray, rng: np.random.Generator,
                 tracked: np.ndarray | None = None, left_view: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The new modes and event codes ``(K, M)`` (:func:`release_on_loss` under the model's priors)."""
        return release_on_loss(modes, perceived, supported, rng, self.model.memory, self.model.config.priors,
                               tracked, left_view)

    def let_go(self, u: Draft) -> None:
        model, mem = self.model, self.model.memory
        let_go_now = u.let_go_now
        if self._gone_moving is not None and np.any(self._gone_moving):  # let go as it left view: at the velocity of
            # the line through its detections since it started moving (one noisy pair is no velocity),
            # with that velocity's standard error per particle
            gone = let_go_now & self._gone_moving[None, :]
            idx = np.flatnonzero(gone.any(axis=0))
            drawn = velocity_draws(mem.perc_vel, mem.velocity_std(model.config.noise.position_std), idx, model.K,
                                   u.rng)
            u.vel[:, idx, :2] = np.where(gone[:, idx, None], drawn, u.vel[:, idx, :2])
        model.roll_released(u.vel, let_go_now & ~u.cover, u.state.supported)
        u.let_go = u.state.let_go_unseen.copy()
        u.let_go[(u.release_codes != 0) & (mem.perceived_prev & ~u.perceived)[None, :]] = u.t
