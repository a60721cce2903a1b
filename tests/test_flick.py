"""Let go in motion: estimator.model.mechanisms.flick."""
import numpy as np

from actions.modes import HELD
from estimator.config import EstimatorConfig
from estimator.model.mechanisms.flick import LetGoMoving
from estimator.observations import Frame
from model_helpers import BALL, CRATE, CUP, MYSTERY, TABLE, make


def test_let_go_in_motion_is_tried_only_out_of_reach_of_the_tracked_hands_and_never_in_paper_mode():
    K = 200
    model = make(EstimatorConfig(particles=K))
    modes = np.zeros((K, 5), np.int8)
    modes[:, BALL] = HELD
    supported = np.ones((K, 5), bool)
    seen = np.zeros(5, bool)
    seen[BALL] = True
    rolling = np.zeros((5, 3))
    rolling[BALL] = [0.5, 0.0, 0.0]
    model.memory.last_pose[BALL, :3] = [0.1, 0.0, 0.14]
    let, logw = model.mechanism(LetGoMoving).let_go_moving(modes, supported, seen, rolling, model._out_of_reach(Frame(0.0), seen),
                                    np.random.default_rng(3))
    assert let[:, BALL].any() and not let[:, [TABLE, CRATE, CUP, MYSTERY]].any()  # no hand tracked
    hand_near = Frame(0.0, {}, {"right": np.array([0.2, 0.0, 0.2])})
    assert not model.mechanism(LetGoMoving).let_go_moving(modes, supported, seen, rolling, model._out_of_reach(hand_near, seen),
                                    np.random.default_rng(3))[0].any()
    hand_far = Frame(0.0, {}, {"right": np.array([1.0, 0.0, 0.2])})
    assert model.mechanism(LetGoMoving).let_go_moving(modes, supported, seen, rolling, model._out_of_reach(hand_far, seen),
                               np.random.default_rng(3))[0].any()
    paper = make(EstimatorConfig.paper())
    assert not any(isinstance(m, LetGoMoving) for m in paper.mechanisms)  # the paper lets nothing go in motion
