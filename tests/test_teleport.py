"""Teleports (Alg. 2 and its moving variant): estimator.model.mechanisms.teleport, on hand-built particle arrays."""
import numpy as np
import pytest

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.teleport import Teleports
from estimator.observations import Detection, Frame
from model_helpers import BALL, CRATE, CUP, YAW90, make
from physics.transforms import pose_compose, pose_inverse


def test_teleport_carries_contents_with_rotation():
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig.off()))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    mem.last_pose[CRATE] = [0.2, 0.1, 0.16, *YAW90]
    mem.last_has_orientation[CRATE] = True
    mem.perc_vel[CRATE, :3] = [0.1, 0.0, 0.0]
    is_in = np.zeros((2, 5, 5), dtype=bool)
    is_in[0, BALL, CRATE] = True  # only particle 0 has the ball in the crate
    poses, vel = st.poses.copy(), st.velocities.copy()
    model.mechanism(Teleports).teleport(poses, vel, np.array([CRATE]), np.zeros(5, bool), is_in, np.random.default_rng(0))
    assert np.allclose(poses[:, CRATE], [0.2, 0.1, 0.16, *YAW90])
    assert np.allclose(vel[:, CRATE, :3], [0.1, 0.0, 0.0])
    # the ball's offset (0.08, 0, -0.02) turned by 90 degrees about z: (0, 0.08, -0.02)
    assert np.allclose(poses[0, BALL], [0.2, 0.18, 0.14, *YAW90])
    assert np.allclose(vel[0, BALL, :3], [0.1, 0.0, 0.0])
    assert np.all(poses[1, BALL] == st.poses[1, BALL]) and np.all(vel[1, BALL] == 0)
    # a container perceived for the first time carries nothing
    poses2, vel2 = st.poses.copy(), st.velocities.copy()
    newly = np.zeros(5, bool)
    newly[CRATE] = True
    model.mechanism(Teleports).teleport(poses2, vel2, np.array([CRATE]), newly, is_in, np.random.default_rng(0))
    assert np.all(poses2[0, BALL] == st.poses[0, BALL])


def test_teleport_with_perception_noise_keeps_the_contents_rigidly_attached():
    model = make(EstimatorConfig(particles=16, noise=NoiseConfig(position_std=0.01, orientation_std=0.4)))
    st = model.initial_state(np.random.default_rng(1))
    mem = model.memory
    mem.last_pose[CRATE] = [0.2, 0.1, 0.16, *YAW90]
    mem.last_has_orientation[CRATE] = True
    is_in = np.zeros((16, 5, 5), dtype=bool)
    is_in[:, BALL, CRATE] = True
    before = pose_compose(pose_inverse(st.poses[:, CRATE]), st.poses[:, BALL])  # ball in the crate's frame
    poses, vel = st.poses.copy(), st.velocities.copy()
    model.mechanism(Teleports).teleport(poses, vel, np.array([CRATE]), np.zeros(5, bool), is_in, np.random.default_rng(2))
    after = pose_compose(pose_inverse(poses[:, CRATE]), poses[:, BALL])
    assert np.allclose(after[:, :3], before[:, :3], atol=1e-9)
    assert np.allclose(np.abs(np.sum(after[:, 3:] * before[:, 3:], axis=-1)), 1.0, atol=1e-9)
    assert poses[:, CRATE, 0].std() > 0.004  # every particle its own noisy teleport
    assert np.all(np.abs(poses[:, CRATE, :3] - [0.2, 0.1, 0.16]) < 0.06)


@pytest.mark.parametrize("moving, hand", [(True, True), (True, False), (False, True)])
def test_an_object_teleported_while_tracked_in_motion_keeps_moving(moving, hand):
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.0), moving_teleports=moving))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    t_ticks = [0.0, 0.1, 0.2]
    for j, t in enumerate(t_ticks):  # the ball rolls along x at 0.9 m/s, seen at 30 Hz
        # in particles 0 and 1 it rolls along x at 0.3 m/s; in particle 2 it rests
        st.velocities[:2, BALL] = [0.3, 0.0, 0.0, 0.0, 10.0, 0.0]
        for f in range(3):
            tf = t + f / 30  # a tracked hand beside it, or none
            hands = {"human/right": np.array([0.1 + 0.9 * tf, 0.0, 0.2])} if hand else {}
            mem.record(Frame(tf, {"ball": Detection(np.array([0.08 + 0.9 * tf, 0.0, 0.14]))}, hands))
        frame = Frame(t + 2 / 30, {}, hands)
        detected = np.zeros(5, bool)
        detected[BALL] = True
        perceived = mem.perceived(frame.t)
        mv = model.move(st, frame, detected, perceived, 0.1, np.random.default_rng(j))
        mem.end_tick(perceived, detected, mem.tick_velocity())
    # at the last tick: tracked since the previous one and jumped 9 cm: teleported in motion
    seen = [0.08 + 0.9 * (0.2 + 2 / 30), 0.0, 0.14]
    assert mv.teleported[BALL]
    if moving:  # started where it was at the update's start (0.1 s before), so physics brings it there
        assert np.allclose(mv.poses[:, BALL, :3], [seen[0] - 0.09, 0.0, 0.14])
        # where it rolled: the velocity over the reasoning period, spinning as it rolls (w = z x v / r)
        assert np.allclose(mv.velocities[:2, BALL], [0.9, 0.0, 0.0, 0.0, 0.9 / 0.03, 0.0])
        if hand:  # where it rested, nothing in the particle's world set it moving: the hand beside it
            # did; it stays (and physics will find it diverging from its moving target: held)
            assert np.all(mv.velocities[2, BALL] == 0.0) and mv.set_moving is None
        else:  # no agent can reach it: it was set moving (flicked) and rolls on, a Push, not a Pick
            assert np.allclose(mv.velocities[2, BALL, :3], [0.9, 0.0, 0.0])
            assert mv.set_moving is not None and mv.set_moving[:, BALL].tolist() == [False, False, True]
        assert np.allclose(mv.target_vel[:, BALL, :3], [0.9, 0.0, 0.0])
        assert np.allclose(mv.target[:, BALL, :3], seen)  # the target reaches the detection at the end
    else:  # Algorithm 2 as the paper: at rest at the detection
        assert np.all(mv.poses[:, BALL, :3] == seen)
        assert np.all(mv.velocities[:, BALL] == 0.0) and np.all(mv.target_vel[:, BALL] == 0.0)


def test_a_teleported_object_is_scored_on_its_physics_not_on_its_teleport_noise():
    """The next update's prediction of a teleported object is where the particle has it, carried on
    at its velocity, minus the noise its teleport drew: two particles that drew different noise but
    move alike predict the same detection."""
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig(position_std=0.01)))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    detected = np.zeros(5, bool)
    detected[BALL] = True
    mem.record(Frame(0.0, {"ball": Detection(np.array([0.08, 0.0, 0.14]))}))
    perceived = mem.perceived(0.0)
    mv = model.move(st, Frame(0.0), detected, perceived, 0.0, np.random.default_rng(1))
    assert mv.teleported[BALL] and np.any(mv.jitter[:, BALL] != 0) and np.all(mv.jitter[:, CUP] == 0)
    assert np.allclose(mv.poses[:, BALL, :2] - mv.jitter[:, BALL, :2], [0.08, 0.0])
    assert np.all(mv.jitter[..., 2] == 0)  # horizontal only: a support undoes the vertical noise
    mem.end_tick(perceived, detected, mem.tick_velocity())
    st.poses, st.jitter = mv.poses.copy(), mv.jitter.copy()
    st.velocities[:, BALL, :3] = [0.5, 0.0, 0.0]
    mv2 = model.move(st, Frame(0.1), np.zeros(5, bool), mem.perceived(0.1), 0.1, np.random.default_rng(2))
    assert np.allclose(mv2.predicted[:, BALL, :2], [0.08 + 0.05, 0.0])
    assert np.all(mv2.jitter == 0)  # nothing teleported this time


@pytest.mark.parametrize("aware, rolling", [(True, False), (False, False), (True, True)])
def test_a_still_objects_noisy_detections_are_not_a_fall_off_an_edge(aware, rolling):
    """A cup standing still, seen by a detector of 1 cm noise: its last detection of one update is
    2.5 cm to one side, of the next 3 cm lower, which by the tick velocities reads as moving along
    (0.25 m/s) then falling (0.3 m/s down). Within the noise (no motion onset), it is no fall off an
    edge and is not teleported (noise_aware_jumps); without it, it is, as before. A cup that really
    slides along at 0.9 m/s and drops is teleported on its fall either way."""
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.01), noise_aware_jumps=aware))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    still = np.array([0.3, 0.3, 0.14])

    def seen(tf, last, tick):
        if rolling:
            return still + [0.9 * tf, 0.0, -0.3 * max(0.0, tf - 0.15)]
        return still + ([0.025, 0.0, 0.0] if last and tick == 1 else [0.0, 0.0, -0.03] if last and tick == 2 else 0.0)

    for j, t in enumerate([0.0, 0.1, 0.2]):
        for f in range(3):
            tf = t + f / 30
            mem.record(Frame(tf, {"cup": Detection(seen(tf, f == 2, j), position_std=0.01)}))
        frame = Frame(t + 2 / 30, {})
        detected = np.zeros(5, bool)
        detected[CUP] = True
        perceived = mem.perceived(frame.t)
        mv = model.move(st, frame, detected, perceived, 0.1, np.random.default_rng(j))
        mem.end_tick(perceived, detected, mem.tick_velocity())
    assert mv.teleported[CUP] == (rolling or not aware)
