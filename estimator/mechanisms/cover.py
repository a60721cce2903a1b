"""Let go behind cover: a held object whose tracked hand hid it from the camera, and that is not
perceived when the hand is seen again without it (or the hand leaves), was let go out of view: put
down where it was lowest, or dropped at a place it was hidden (:func:`~estimator.holding.let_go_out_of_view`);
an object pushed out of view slides around the hand that pushes it (the push grip). Not in the
paper's mode."""
from __future__ import annotations

from ..holding import let_go_out_of_view
from . import Draft, Mechanism


class LetGoBehindCover(Mechanism):
    """Fills :attr:`Draft.cover_t` (when each object let go now behind cover was let go), adds the
    proposal's log-weight factor and the push grips (:attr:`Draft.grip`)."""

    def release(self, u: Draft) -> None:
        model, cfg = self.model, self.model.config
        cover_t, proposal, u.grip = let_go_out_of_view(u.state, u.poses, u.vel, u.modes, u.release_codes, u.frame,
                                                       model.memory, u.following, u.perceived, u.detected,
                                                       cfg.priors, cfg.noise, u.rng, cfg.reasoner.push_lift,
                                                       cfg.hands.measurement_std, model.round)
        u.cover_t = cover_t
        u.proposal = proposal
