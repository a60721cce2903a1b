"""Held objects in the scene model (estimator/holding.py): release at loss by hand state, targets."""
import numpy as np

from actions.modes import FREE, HELD, ModePriors
from estimator.config import ReasonerConfig
from estimator.holding import release_on_loss
from estimator.model import initial_poses
from estimator.observations import Detection, Frame
from estimator.perception_memory import PerceptionMemory
from physics.scene import scene_from_dict


def _memory(hand_end):
    sc = scene_from_dict({"objects": [{"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08},
                                       "pose": {"position": [0.1, 0.0, 0.04]}}]})
    mem = PerceptionMemory(sc, initial_poses(sc)[0], ReasonerConfig(), True)
    mem.record(Frame(0.0, {"cup": Detection(np.array([0.1, 0.0, 0.7]))}, {"h": np.array([0.1, 0.0, 0.78])}))
    for k in range(1, 4):
        mem.record(Frame(0.1 * k, {}, {"h": np.array(hand_end)}))
    mem.perceived_prev = np.array([True])
    return mem


def test_the_share_released_at_loss_follows_the_hand_state():
    """4000 particles: the released share is within 4 binomial standard errors of the prior of the
    hand's state (carried 0.1, still 0.6); nothing is released while the object is perceived."""
    priors = ModePriors(release_on_loss_carried=0.1, release_on_loss_still=0.6, carry_distance=0.05)
    K = 4000
    modes = np.full((K, 1), HELD, np.int8)
    for hand_end, p in (([0.4, 0.0, 0.78], 0.1), ([0.11, 0.0, 0.78], 0.6)):
        new, codes = release_on_loss(modes, np.array([False]), np.zeros((K, 1), bool), np.random.default_rng(3),
                                     _memory(hand_end), priors, np.array([True]))
        share = np.mean(new[:, 0] == FREE)
        assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / K), (hand_end, share)
        assert np.all((codes != 0) == (new == FREE))
    new, _ = release_on_loss(modes, np.array([True]), np.zeros((K, 1), bool), np.random.default_rng(3),
                             _memory([0.4, 0.0, 0.78]), priors, np.array([True]))
    assert np.all(new == HELD)
