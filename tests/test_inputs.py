"""estimator.model.inputs: what the frames since the last reasoning step had in common."""
import numpy as np
import pytest

from estimator.model.inputs import StepInputs
from estimator.observations import Frame
from physics.scene import CameraSpec

SCENE_CAM = CameraSpec(position=(1.0, 0.0, 1.0), target=(0.0, 0.0, 0.0))
HEAD = CameraSpec(position=(0.0, 1.0, 1.5), target=(0.0, 0.0, 0.5))


def test_detections_are_gathered_over_the_frames_and_emptied_by_a_step():
    inputs = StepInputs(3, SCENE_CAM)
    inputs.add(Frame(0.0), np.array([True, False, False]))
    inputs.add(Frame(0.04), np.array([False, False, True]))
    detected, cameras = inputs.take()
    assert detected.tolist() == [True, False, True] and cameras is None  # the scene's camera only
    assert inputs.take()[0].tolist() == [False, False, False]
    assert inputs.frame.t == 0.04 and inputs.t_frame == 0.04


def test_the_cameras_of_the_frames_each_once_with_the_scenes_when_a_frame_had_none():
    inputs = StepInputs(1, SCENE_CAM)
    inputs.add(Frame(0.0, cameras={"head": HEAD}), np.zeros(1, bool))
    inputs.add(Frame(0.03, cameras={"head": HEAD}), np.zeros(1, bool))
    assert inputs.take()[1] == (HEAD,)
    inputs.add(Frame(0.06, cameras={"head": HEAD}), np.zeros(1, bool))
    inputs.add(Frame(0.09), np.zeros(1, bool))  # the scene's camera took this one
    assert inputs.take()[1] == (SCENE_CAM, HEAD)


def test_hands_are_kept_across_steps_and_time_must_increase():
    inputs = StepInputs(1)
    inputs.add(Frame(0.0, hands={"right": np.array([0.1, 0.0, 0.9])}), np.zeros(1, bool))
    inputs.take()
    inputs.add(Frame(0.1), np.zeros(1, bool))  # no hand in this frame: the last ones stay
    assert list(inputs.last_hands) == ["right"]
    with pytest.raises(ValueError, match="frame time must increase"):
        inputs.check_time(0.1)
    inputs.check_time(0.2)
