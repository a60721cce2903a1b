import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physics import transforms as tf


def test_quaternion_ops_match_scipy():
    rng = np.random.default_rng(1)
    a = Rotation.random(20, random_state=2)
    b = Rotation.random(20, random_state=3)
    q = tf.quat_multiply(a.as_quat(), b.as_quat())
    assert np.allclose(np.abs(np.sum(q * (a * b).as_quat(), axis=1)), 1.0)
    v = rng.normal(size=(20, 3))
    assert np.allclose(tf.quat_rotate(a.as_quat(), v), a.apply(v))


def test_pose_inverse_and_carry():
    rng = np.random.default_rng(4)
    pose = np.concatenate([rng.normal(size=(5, 3)), Rotation.random(5, random_state=5).as_quat()], axis=1)
    ident = tf.pose_compose(pose, tf.pose_inverse(pose))
    assert np.allclose(ident[:, :3], 0, atol=1e-12)
    assert np.allclose(np.abs(ident[:, 6]), 1.0)
    # a child 10 cm above its parent stays 10 cm "above" in the parent's frame after a 90 deg yaw
    parent0 = np.array([0, 0, 0, 0, 0, 0, 1.0])
    parent1 = np.concatenate([[1, 0, 0], Rotation.from_euler("x", 90, degrees=True).as_quat()])
    child = np.array([0, 0, 0.1, 0, 0, 0, 1.0])
    moved = tf.carry_pose(child, parent0, parent1)
    assert np.allclose(moved[:3], [1, -0.1, 0], atol=1e-12)


def test_normalize_rejects_zero_and_rotvec_roundtrip():
    with pytest.raises(ValueError):
        tf.quat_normalize([0, 0, 0, 0])
    r = np.array([[0.1, -0.2, 0.3], [0, 0, 0]])
    assert np.allclose(tf.quat_to_rotvec(tf.quat_from_rotvec(r)), r, atol=1e-12)
    assert np.isclose(tf.quat_angle([0, 0, 0, 1], tf.quat_from_rotvec([0, 0, 0.5])), 0.5)


def test_rotation_matrices_turn_vectors_as_the_quaternions_do():
    rng = np.random.default_rng(5)
    q = rng.normal(size=(50, 4)) * 3.0  # not normalised: the function normalises
    v = rng.normal(size=(50, 3))
    R = tf.quat_to_matrix(q)
    assert R.shape == (50, 3, 3)
    assert np.allclose(np.einsum("nij,nj->ni", R, v), tf.quat_rotate(tf.quat_normalize(q), v), atol=1e-12)
    assert np.allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-12)
    assert tf.quat_to_matrix(q.reshape(5, 10, 4)).shape == (5, 10, 3, 3)


def test_link_and_centre_of_mass_frames_convert_both_ways():
    from physics.transforms import com_from_link, link_from_com, pose_inverse

    rng = np.random.default_rng(3)
    inertial = np.concatenate([rng.normal(0, 0.02, (4, 3)), _unit(rng.normal(size=(4, 4)))], axis=1)
    poses = np.concatenate([rng.normal(size=(5, 4, 3)), _unit(rng.normal(size=(5, 4, 4)))], axis=-1)
    vel = rng.normal(size=(5, 4, 6))
    com, cvel = com_from_link(poses, vel, inertial)
    back, bvel = link_from_com(com, cvel, inertial, pose_inverse(inertial))
    assert np.allclose(back[..., :3], poses[..., :3]) and np.allclose(bvel, vel)
    assert np.allclose(np.abs(np.sum(back[..., 3:] * poses[..., 3:], axis=-1)), 1.0)  # same rotation
    # the centre of mass moves with the body: v_com = v_link + w x (R c)
    c = com[..., :3] - poses[..., :3]
    assert np.allclose(cvel[..., :3], vel[..., :3] + np.cross(vel[..., 3:], c)) and np.allclose(cvel[..., 3:], vel[..., 3:])


def _unit(q):
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
