"""After physics, the Place / Release rules: estimator.model.settle."""
from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD, PLACE
from actions.push import LET_GO_T, PICK_T, REF_Z
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.worlds.pool import BatchOutput
from model_helpers import CUP, TABLE, cup_held_seen_still, make


@pytest.mark.parametrize("still_unacted, rested", [(False, True), (True, True), (True, False)])
def test_place_a_held_object_perceived_at_rest_on_a_support(still_unacted, rested):
    """A cup held in both particles, seen at rest on the table: let go where it rests on the table
    (Place, once physics confirms it), held on where it floats. Seen still all along (no motion
    onset) after resting on the table in its particles, or on a support where the particle holds it,
    its episode was a particle's physics, not an agent's: with ``still_unacted`` no event; but one
    never at rest in its particle and held in the air there is held by someone (its episode is not
    silent)."""
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig(), still_unacted=still_unacted))
    st = model.initial_state(np.random.default_rng(0))
    if rested:
        st.holds[:, CUP, REF_Z] = 0.14  # it had rested on the table in both particles
    t, perceived, mv, modes, out = cup_held_seen_still(model, st, 0.14, [
        [[0.27, 0.27, 0.1], [0.33, 0.33, 0.18]],    # particle 0: the cup sits on the table
        [[0.27, 0.27, 0.3], [0.33, 0.33, 0.38]]])   # particle 1: 20 cm above it
    aabbs = out.aabbs
    s = model.settle(st, replace(mv, modes=modes.copy()), out, t, 0.08, perceived, perceived)
    assert list(s.modes[:, CUP]) == [FREE, HELD] and list(s.codes[:, CUP]) == [0, 0]
    if still_unacted and not rested:  # silent on the table (particle 0), not in the air (particle 1)
        assert s.holds[0, CUP, PICK_T] == -np.inf and np.isnan(s.holds[1, CUP, PICK_T])
    assert s.on_top[0, CUP, TABLE] and s.supported[0, CUP] and not s.supported[1, CUP]
    # the Place waits for physics: at the next update the cup rests where it was let go (as perceived)
    assert s.holds[0, CUP, LET_GO_T] == pytest.approx(t - model.config.reasoner.place_dwell)
    assert np.isnan(s.holds[1, CUP, LET_GO_T])
    st2 = st.replace(modes=s.modes.copy(), holds=s.holds, supported=s.supported)
    poses = st.poses.copy()
    poses[:, CUP, 2] = 0.14
    out2 = BatchOutput(poses, np.zeros_like(st.velocities), s.modes.copy(), np.zeros((2, 5)), aabbs,
                       np.ones(2, bool), np.zeros((2, 5)))
    s2 = model.settle(st2, replace(mv, modes=s.modes.copy()), out2, t + 0.08, 0.08, perceived, perceived)
    # dated when it came to rest, a dwell before the let-go rule fired
    assert list(s2.modes[:, CUP]) == [FREE, HELD]
    if still_unacted:
        assert list(s2.codes[:, CUP]) == [0, 0]
        return
    assert list(s2.codes[:, CUP]) == [PLACE, 0] and s2.times[0, CUP] == pytest.approx(t - model.config.reasoner.place_dwell)


def test_a_held_object_seen_still_above_its_support_by_more_than_lift_is_not_let_go():
    """A cup held in both particles, seen still: 1 cm above the table in particle 0 (put down: let
    go), 2.5 cm above it in particle 1 (within place_gap, 3 cm, but more than lift, 2 cm: a hand
    holding it still above the table; let go it would drop 2.5 cm and be held again)."""
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    rule, hr = model.episode_rule, model.config.reasoner
    assert rule.lift < 0.025 < hr.place_gap
    st = model.initial_state(np.random.default_rng(0))
    t, perceived, mv, modes, out = cup_held_seen_still(model, st, 0.15, [
        [[0.27, 0.27, 0.11], [0.33, 0.33, 0.19]],     # 1 cm above the table
        [[0.27, 0.27, 0.125], [0.33, 0.33, 0.205]]])  # 2.5 cm above it
    s = model.settle(st, replace(mv, modes=modes.copy()), out, t, 0.08, perceived, perceived)
    assert list(s.supported[:, CUP]) == [True, True]  # both within place_gap: supported
    assert list(s.modes[:, CUP]) == [FREE, HELD]
