"""Let go behind cover: a held object whose tracked hand hid it from the camera, and that is not
perceived when the hand is seen again without it (or the hand leaves), was let go out of view: put
down where it was lowest, or dropped at a place it was hidden (:func:`~estimator.model.hidden.let_go_out_of_view`);
an object pushed out of view slides around the hand that pushes it (the push grip). Not in the
paper's mode."""
from __future__ import annotations

import numpy as np

from ..hidden import let_go_out_of_view, places_after_update
from .base import ArraySpec, Draft, Mechanism


class LetGoBehindCover(Mechanism):
    """Fills :attr:`Draft.cover_t` (when each object let go now behind cover was let go), adds the
    proposal's log-weight factor and the push grips (:attr:`Draft.grip`)."""

    arrays = {"hidden_at": ArraySpec((3,)), "hidden_t": ArraySpec((), float, -np.inf),
              "hidden_n": ArraySpec((), np.int32, 0), "down_at": ArraySpec((3,)),
              "down_t": ArraySpec((), float, -np.inf), "rest_at": ArraySpec((3,)),
              "rest_t": ArraySpec((), float, -np.inf), "push_grip": ArraySpec((), float, np.nan)}
    """Where (and when) a held object was while its tracked hand kept it out of view, where it was
    lowest then, where it last rested out of view (see :class:`~estimator.state.ParticleState`), and
    the grip of the hand that pushes it out of view (NaN: none)."""

    def commit(self, state, p, w, rng) -> dict:
        """The places the held objects were hidden at, lowest and last at rest after the update
        (:func:`~estimator.model.hidden.places_after_update`), and the push grips."""
        names = ("hidden_at", "hidden_t", "hidden_n", "down_at", "down_t", "rest_at", "rest_t")
        out = dict(zip(names, places_after_update(state, w.evidence, w.settled, p.t, rng,
                                                  self.model.config.visibility_threshold)))
        out["push_grip"] = p.move.push_grip  # set by this mechanism's release hook at every update
        return out

    def release(self, u: Draft) -> None:
        model, cfg = self.model, self.model.config
        cover_t, proposal, u.grip = let_go_out_of_view(u.state, u.poses, u.vel, u.modes, u.release_codes, u.frame,
                                                       model.memory, u.following, u.perceived, u.detected,
                                                       cfg.priors, cfg.noise, u.rng, cfg.reasoner.push_lift,
                                                       cfg.hands.measurement_std, model.round)
        u.cover_t = cover_t
        u.proposal = proposal
