"""estimator.model.mechanisms.static_clip: paths to targets stop at static geometry, and what physics
left inside it is pushed out."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.static_clip import StaticClip
from model_helpers import BALL, CUP, TABLE, make


def test_a_held_ball_carried_into_the_table_stops_at_its_top_with_no_target_velocity():
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    clip = model.mechanism(StaticClip)
    st = model.initial_state(np.random.default_rng(0))
    poses = st.poses.copy()
    poses[:, BALL, :3] = [0.3, -0.3, 0.2]  # above the table (top at 0.1 m), away from the crate
    target = poses.copy()
    target[0, BALL, :3] = [0.3, -0.3, 0.0]  # into the table
    target[1, BALL, :3] = [0.3, -0.3, 0.15]  # stays above it
    target_vel = np.ones((2, 5, 6))
    which = np.zeros((2, 5), bool)
    which[:, BALL] = True
    clip.clip_targets(poses, target, target_vel, which)
    assert 0.1 + 0.03 - 0.005 <= target[0, BALL, 2] <= 0.1 + 0.03 + 0.005  # on the top, radius 3 cm
    assert np.all(target_vel[0, BALL] == 0.0) and np.all(target_vel[1, BALL] == 1.0)
    assert target[1, BALL, 2] == 0.15 and np.all(target_vel[:, CUP] == 1.0)  # untouched


def test_an_object_left_deep_inside_the_table_is_pushed_out_and_none_when_clipping_is_off():
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    st = model.initial_state(np.random.default_rng(0))
    poses = st.poses.copy()
    poses[0, CUP, :3] = [0.3, 0.3, 0.06]  # its bottom 3 cm into the table
    aabbs = np.zeros((2, 5, 2, 3))
    aabbs[..., 0, :], aabbs[..., 1, :] = poses[..., None, :3][..., 0, :] - 0.04, poses[..., :3] + 0.04
    out = model.mechanism(StaticClip).after_physics(poses, aabbs)
    assert out is not poses and out[0, CUP, 2] >= 0.1 + 0.04 - 0.011  # within the 1 cm the invariant allows
    assert np.array_equal(out[1], poses[1]) and np.array_equal(out[:, TABLE], poses[:, TABLE])
    off = make(EstimatorConfig(particles=2, noise=NoiseConfig(), static_clip=False))
    assert not any(isinstance(m, StaticClip) for m in off.mechanisms)


def test_a_free_objects_detection_sunk_into_the_table_is_lifted_onto_it_where_it_was_seen():
    """The tracker's error sank the cup's detection 2 cm into the table, 5 cm beside where the
    particle has it: the target goes up onto the table top above the detection (its horizontal
    position is the evidence), with no target velocity; a detection 2 mm low (within
    CLIP_DEPTH) and one above the table are left alone."""
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig()))
    clip = model.mechanism(StaticClip)
    st = model.initial_state(np.random.default_rng(0))
    target = st.poses.copy()  # the cup (8 cm tall, frame at its centre) stands on the top at 0.1 m
    target[:, CUP, :3] = [[0.35, 0.3, 0.14 - 0.02], [0.35, 0.3, 0.14 - 0.002], [0.35, 0.3, 0.16]]
    seen = target.copy()
    target_vel = np.ones((3, 5, 6))
    which = np.zeros((3, 5), bool)
    which[:, CUP] = True
    clip.lift_targets(target, target_vel, which)
    assert np.array_equal(target[0, CUP, :2], seen[0, CUP, :2])  # where it was seen, horizontally
    assert abs(target[0, CUP, 2] - 0.14) < 1e-3  # on the top, not in it
    assert np.all(target_vel[0, CUP] == 0.0) and np.all(target_vel[1:, CUP] == 1.0)
    assert np.array_equal(target[1:], seen[1:]) and np.array_equal(target[:, BALL], seen[:, BALL])
