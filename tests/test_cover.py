"""estimator.model.mechanisms.cover: let go behind cover. Its array functions are tested in
test_holding.py and test_hidden.py; here, what the mechanism keeps and what its hook hands on."""
import numpy as np

from actions.modes import HELD
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.cover import LetGoBehindCover
from estimator.observations import Detection, Frame
from model_helpers import CUP, make


def test_the_places_a_hidden_object_was_are_kept_per_particle_from_nothing_known():
    model = make(EstimatorConfig(particles=4, noise=NoiseConfig()))
    st = model.initial_state(np.random.default_rng(0))
    for name, spec in LetGoBehindCover.arrays.items():
        a = getattr(st, name)
        assert a.shape[:2] == (4, 5) and a.dtype == np.dtype(spec.dtype), name
    assert np.all(st.hidden_t == -np.inf) and np.all(st.hidden_n == 0) and np.all(np.isnan(st.push_grip))


def test_nothing_held_out_of_view_nothing_let_go_behind_cover_and_the_proposal_is_unweighted():
    model = make(EstimatorConfig(particles=4, noise=NoiseConfig(hand_occlusion=0.5)))
    st = model.initial_state(np.random.default_rng(0))
    st.modes[:, CUP] = HELD  # held in every particle, and seen: no let-go out of view
    model.memory.record(Frame(0.0, {"cup": Detection(np.array([0.3, 0.3, 0.2]))}))
    detected = np.zeros(5, bool)
    detected[CUP] = True
    mv = model.move(st, Frame(0.0), detected, model.memory.perceived(0.0), 0.0, np.random.default_rng(1))
    assert np.all(np.isnan(mv.cover_t)) and np.all(mv.proposal_log_weight == 0.0)
    assert np.all(np.isnan(mv.push_grip[:, CUP]))  # detected: no push grip
