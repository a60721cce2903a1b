"""estimator.model.hand_memory: the hand nearest to each object, its offset, and how far it carried it."""
import numpy as np

from estimator.config import ReasonerConfig
from estimator.model import initial_poses
from estimator.model.hand_memory import HAND_RADIUS
from estimator.model.perception_memory import PerceptionMemory
from estimator.observations import Detection, Frame
from physics.scene import scene_from_dict


def _memory(follow_hands=True):
    sc = scene_from_dict({"objects": [
        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "pose": {"position": [0.0, 0.0, 0.04]}},
        {"id": "box", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [1.0, 0.0, 0.025]}}]})
    return PerceptionMemory(sc, initial_poses(sc)[0], ReasonerConfig(), follow_hands)


def test_an_object_near_a_hand_follows_it_and_one_beyond_reach_does_not():
    mem = _memory()
    hand = np.array([0.0, 0.0, 0.8])
    frame = Frame(0.0, {"cup": Detection(np.array([0.0, 0.0, 0.72])),
                        "box": Detection(np.array([HAND_RADIUS + 0.05, 0.0, 0.8]))}, {"right": hand})
    mem.record(frame)
    assert mem.hold_hand == ["right", None] and mem.following_hand(frame).tolist() == [True, False]
    assert np.allclose(mem.hold_offset[0], [0.0, 0.0, -0.08])
    assert np.allclose(mem.hand_target(frame, 0), mem.hand_position("right") + mem.hold_offset[0])
    assert mem.hand_target(frame, 1) is None and np.isnan(mem.hand_heights(frame, np.array([False, True]))[1])
    assert not _memory(follow_hands=False).following_hand(frame).any()


def test_the_hand_travel_since_the_object_was_last_seen():
    mem = _memory()
    mem.record(Frame(0.0, {"cup": Detection(np.array([0.0, 0.0, 0.72]))}, {"right": np.array([0.0, 0.0, 0.8])}))
    before = mem.hand_position("right").copy()
    for k in range(1, 10):  # the hand moves on, the cup is not seen
        mem.record(Frame(k / 30, {}, {"right": np.array([0.01 * k, 0.0, 0.8])}))
    travel = mem.hand_travel()
    assert np.isclose(travel[0], np.linalg.norm(mem.hand_position("right") - before)) and travel[0] > 0.03
    assert np.isnan(travel[1])  # never near a hand
