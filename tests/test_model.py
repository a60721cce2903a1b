"""The scene model's pieces alone, on hand-built particle arrays (no worlds)."""
import math
from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD, PLACE, RELEASE
from actions.push import LET_GO_T, PICK_T, REF_Z
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.likelihood import Evidence
from estimator.mechanisms.flick import LetGoMoving
from estimator.mechanisms.follow_hand import FollowHands
from estimator.mechanisms.process_noise import ProcessNoise
from estimator.mechanisms.release import ReleaseOnLoss
from estimator.mechanisms.rest_fusion import FusionAtRest
from estimator.mechanisms.teleport import Teleports
from estimator.model import SceneModel, initial_poses
from estimator.regularisation import regularisation_kernels, regularise
from estimator.params import param_bounds
from estimator.observations import Detection, Frame
from estimator.perception_memory import PerceptionMemory
from estimator.pool import BatchOutput
from physics.scene import scene_from_dict
from physics.transforms import pose_compose, pose_inverse

TABLE, CRATE, BALL, CUP, MYSTERY = range(5)
YAW90 = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])


def scene():
    return scene_from_dict({"objects": [
        {"id": "table", "static": True, "box": {"size": [1.0, 1.0, 0.1]}, "pose": {"position": [0, 0, 0.05]}},
        {"id": "crate", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01}, "pose": {"position": [0, 0, 0.16]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.08, 0.0, 0.14]}},
        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "pose": {"position": [0.3, 0.3, 0.14]}},
        {"id": "mystery", "sphere": {"radius": 0.02}}]})  # no pose: unknown until perceived


def make(config):
    sc = scene()
    memory = PerceptionMemory(sc, initial_poses(sc)[0], config.reasoner, config.follow_hands)
    base = np.tile([0.5, 0.0, 0.0, 0.1, 0.2], (len(sc.objects), 1))
    return SceneModel(sc, config, base, memory)


def test_initial_state_parks_unknown_objects_and_draws_parameters_from_their_priors():
    nz = NoiseConfig(position_std=0.01)
    model = make(EstimatorConfig(particles=64, noise=nz))
    st = model.initial_state(np.random.default_rng(0))
    assert list(model.known) == [True, True, True, True, False]
    assert np.all(st.poses[:, MYSTERY, :3] == [50.0 + 3.0 * MYSTERY, 50.0, -50.0])
    assert np.all(st.poses[:, TABLE, :3] == [0, 0, 0.05])  # static: never perturbed
    spread = st.poses[:, BALL, :3] - [0.08, 0.0, 0.14]
    assert 0.006 < spread[:, :2].std() < 0.014 and np.all(spread[:, :2] != 0)
    assert np.all(spread[:, 2] == 0)  # horizontally only: not pushed into its support nor dropped on it
    fr = st.params[:, 1:, 0]
    assert np.all((fr >= 0.3) & (fr <= 1.0)) and fr.std() > 0.1
    assert np.all(st.params[:, TABLE] == [0.5, 0.0, 0.0, 0.1, 0.2])
    mass = st.params[:, 1:, 4] / 0.2
    assert np.all((mass >= 0.8) & (mass <= 1.25))
    assert st.modes.dtype == np.int8 and np.all(st.modes == FREE) and np.all(st.log_weights == 0)


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


def test_move_teleports_a_first_sighting_and_makes_it_known():
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.01)))
    st = model.initial_state(np.random.default_rng(0))
    frame = Frame(0.5, {"mystery": Detection(np.array([0.1, -0.1, 0.2]))})
    detected = model.memory.record(frame)
    perceived = model.memory.perceived(0.5)
    mv = model.move(st, frame, detected, perceived, 0.0, np.random.default_rng(3))
    assert list(mv.teleported) == [False, False, False, False, True] and model.known[MYSTERY]
    assert np.all(np.abs(mv.poses[:, MYSTERY, :3] - [0.1, -0.1, 0.2]) < 0.05)
    assert np.all(mv.predicted[:, MYSTERY, :3] == [50.0 + 3.0 * MYSTERY, 50.0, -50.0])
    assert np.all(mv.depenetrate[:, MYSTERY]) and np.all(mv.check[:, MYSTERY])
    assert np.all(mv.target[:, MYSTERY, :3] == [0.1, -0.1, 0.2])  # checked against the perception itself


def test_held_targets_follow_the_tracked_hand_or_drift():
    frame = Frame(1.0, {}, {"human/right": np.array([1.0, 0.0, 1.0])})
    for follow in (True, False):
        model = make(EstimatorConfig(particles=3, noise=NoiseConfig(held_drift_std=0.05, held_offset_std=0.0),
                                     follow_hands=follow))
        st = model.initial_state(np.random.default_rng(0))
        model.memory.record(frame)  # the hand's first position: the filter's
        model.memory.hold_hand[CUP] = "human/right"
        model.memory.hold_offset[CUP] = [0.0, 0.0, -0.05]
        modes = st.modes.copy()
        modes[:2, CUP] = HELD  # held in particles 0 and 1, free in 2
        none = np.zeros(5, bool)
        target, target_vel, err = model.mechanism(FollowHands).held_targets(frame, st.poses, modes, none, none, 0.25,
                                                     np.random.default_rng(7), st.hold_error)
        assert np.all(err == 0)
        if follow:
            assert np.allclose(target[:2, CUP, :3], [1.0, 0.0, 0.95])
        else:  # no hand to follow: a drift of held_drift_std * sqrt(dt), the same draws as here
            drift = np.random.default_rng(7).normal(0.0, 0.05 * math.sqrt(0.25), (2, 3))
            assert np.allclose(target[:2, CUP, :3], st.poses[:2, CUP, :3] + drift)
        assert np.all(target[2, CUP] == st.poses[2, CUP]) and np.all(target_vel == 0)


@pytest.mark.parametrize("moving, detected, teleported, z, velocity",
                         [(False, False, False, 0.4, 1.0), (True, True, True, 0.4, 1.0), (True, True, False, 0.4, 0.0),
                          (True, False, False, 0.7, 1.0)])
def test_held_target_of_a_perceived_object_is_its_perception_without_drift(moving, detected, teleported, z, velocity):
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig(held_drift_std=0.05), follow_hands=False,
                                 moving_teleports=moving))
    st = model.initial_state(np.random.default_rng(0))
    model.memory.record(Frame(0.0, {"cup": Detection(np.array([0.3, 0.3, 0.3]))}))
    model.memory.record(Frame(0.1, {"cup": Detection(np.array([0.3, 0.3, 0.4]))}))
    modes = st.modes.copy()
    modes[:, CUP] = HELD
    perceived = model.memory.perceived(0.4)
    tele, det = np.zeros(5, bool), np.zeros(5, bool)
    tele[CUP], det[CUP] = teleported, detected
    target, target_vel, _ = model.mechanism(FollowHands).held_targets(Frame(0.4), st.poses, modes, det, perceived, 0.3,
                                               np.random.default_rng(0), st.hold_error, tele)
    # at the detection; with moving teleports, one not detected in this update (last seen 0.3 s ago
    # moving up at 1 m/s) is where that detection carried on puts it now, and goes on
    assert np.allclose(target[:, CUP, :3], [0.3, 0.3, z])
    # the finite difference (m/s); with moving teleports only an object placed at its detection now
    # has one (the divergence test carries its target on at it), or one carried on
    assert np.allclose(target_vel[:, CUP, :3], [0.0, 0.0, velocity])


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


def test_process_noise_touches_only_unperceived_free_known_dynamic_objects():
    nz = NoiseConfig(process_position_std=0.01, process_orientation_std=0.1, motion_noise=0.5)
    model = make(EstimatorConfig(particles=4, noise=nz))
    st = model.initial_state(np.random.default_rng(0))
    poses = st.poses.copy()
    modes = st.modes.copy()
    modes[:, CUP] = HELD    # held: moved by its hand, not by noise
    modes[3, BALL] = HELD   # the ball is held in particle 3 only
    perceived = np.zeros(5, bool)
    perceived[CRATE] = True
    supported = np.ones((4, 5), bool)
    resting = np.zeros((4, 5), bool)
    resting[2, BALL] = True  # at rest on its support in particle 2: a resting object does not wander
    last_motion = np.zeros((4, 5))
    last_motion[0, BALL] = 0.1  # rolled 10 cm: large model error, capped
    jolted = model.mechanism(ProcessNoise).process_noise(poses, modes, perceived, supported, resting, last_motion, 0.5,
                                 np.random.default_rng(4))
    changed = np.any(poses != st.poses, axis=-1)
    expect = np.zeros((4, 5), bool)
    expect[:2, BALL] = True  # not the static table, the perceived crate, the held cup, the unknown mystery
    assert np.array_equal(changed, expect)
    assert np.all(np.any(poses[:2, BALL, 3:] != st.poses[:2, BALL, 3:], axis=-1))  # orientations too
    assert np.allclose(np.linalg.norm(poses[..., 3:], axis=-1), 1.0)
    # std: sqrt(0.01^2 * 0.5 + (0.5 * rolled)^2) capped at max_jitter_std (0.01); jolted above 2 mm
    assert np.array_equal(jolted, expect)
    assert np.all(np.abs(poses[0, BALL, :3] - st.poses[0, BALL, :3]) < 5 * nz.max_jitter_std)


def test_held_target_adds_each_particles_offset_error_to_the_tracked_hand():
    """With held_offset_std, each particle's held object is at the hand + offset + its own error,
    which starts at zero and walks (hand_offset_walk, the same draws); detected objects reset it."""
    frame = Frame(1.0, {}, {"human/right": np.array([1.0, 0.0, 1.0])})
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig(held_offset_std=0.02, held_offset_time=0.5)))
    st = model.initial_state(np.random.default_rng(0))
    model.memory.record(frame)
    model.memory.hold_hand[CUP] = "human/right"
    model.memory.hold_offset[CUP] = [0.0, 0.0, -0.05]
    modes = st.modes.copy()
    modes[:, CUP] = HELD
    before = np.zeros((3, 5, 3))
    before[:, CUP] = [[0.01, 0.0, 0.0], [0.0, -0.01, 0.0], [0.0, 0.0, 0.0]]
    none = np.zeros(5, bool)
    target, _, err = model.mechanism(FollowHands).held_targets(frame, st.poses, modes, none, none, 0.1, np.random.default_rng(3), before)
    from estimator.held import hand_offset_walk
    expect = hand_offset_walk(before[:, CUP], 0.1, 0.02, 0.5, np.random.default_rng(3))
    np.testing.assert_allclose(err[:, CUP], expect)
    np.testing.assert_allclose(target[:, CUP, :3], np.array([1.0, 0.0, 0.95]) + expect)
    assert np.all(err[:, [i for i in range(5) if i != CUP]] == 0)
    detected = none.copy()
    detected[CUP] = True
    model.memory.last_seen[CUP] = frame.t  # detected in this update's last frame
    _, _, err = model.mechanism(FollowHands).held_targets(frame, st.poses, modes, detected, detected, 0.1, np.random.default_rng(3), before)
    assert np.all(err == 0)
    # detected in an earlier frame of the update only: the hand has moved on since (its filtered
    # position, over the frames recorded since), and the object with it, plus each particle's error
    from estimator.observations import Detection
    mem = model.memory
    mem.record(Frame(1.1, {"cup": Detection(np.array([1.0, 0.0, 0.95]))}, {"human/right": [1.0, 0.0, 1.0]}))
    later = Frame(1.2, {}, {"human/right": [1.06, 0.0, 1.0]})
    mem.record(later)
    moved = mem.hand_position("human/right") - mem.hold_hand_position[CUP]
    assert 0.0 < moved[0] <= 0.06 and np.allclose(moved[1:], 0.0)
    stale = mem.stale_in_hand(later) & detected  # as the model's move computes them
    target, _, err = model.mechanism(FollowHands).held_targets(later, st.poses, modes, detected, detected, 0.1, np.random.default_rng(3),
                                        before, None, None, mem.detections_now(stale, later.t), stale)
    np.testing.assert_allclose(err[:, CUP], expect)
    np.testing.assert_allclose(target[:, CUP, :3], np.array([1.0, 0.0, 0.95]) + moved + expect)


def test_release_on_loss_depends_on_whether_the_tracked_hand_carried_the_object():
    """At the loss of a held object whose hand is tracked: release_on_loss_carried when the hand
    moved more than carry_distance since the object was last seen, else release_on_loss_still;
    release_on_loss without a tracked hand. Probabilities 0 and 1 make the outcome certain."""
    from actions.modes import ModePriors
    priors = ModePriors(release_on_loss=1.0, release_on_loss_carried=0.0, release_on_loss_still=1.0,
                        release=0.0, carry_distance=0.05)
    for hand_end, tracked, expect_released in (([0.3, 0.0, 0.8], True, False), ([0.11, 0.0, 0.8], True, True),
                                               ([0.3, 0.0, 0.8], False, True)):
        model = make(EstimatorConfig(particles=4, noise=NoiseConfig(), priors=priors))
        st = model.initial_state(np.random.default_rng(0))
        hand = {"human/right": np.array([0.1, 0.0, 0.8])}
        model.memory.record(Frame(0.0, {"cup": Detection(np.array([0.1, 0.0, 0.7]))}, hand))
        for k in range(1, 4):
            model.memory.record(Frame(0.1 * k, {}, {"human/right": np.array(hand_end)}))
        model.memory.perceived_prev = model.memory.perceived(0.0)
        modes = st.modes.copy()
        modes[:, CUP] = HELD
        perceived = model.memory.perceived(1.0)
        assert not perceived[CUP] and model.memory.perceived_prev[CUP]
        trk = model.memory.following_hand(Frame(1.0, {}, {"human/right": np.array(hand_end)})) if tracked \
            else np.zeros(5, bool)
        new, codes = model.mechanism(ReleaseOnLoss).releases(modes, perceived, st.supported, np.random.default_rng(1), trk)
        assert np.all((new[:, CUP] == FREE) == expect_released), (hand_end, tracked)


def test_release_on_loss_and_later_releases():
    from actions.modes import ModePriors
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig(), priors=ModePriors(release_on_loss=1.0, release=0.0)))
    model.memory.perceived_prev[CUP] = True  # the cup was perceived at the last update, no longer
    modes = np.zeros((2, 5), np.int8)
    modes[:, [BALL, CUP, CRATE]] = HELD
    perceived = np.zeros(5, bool)
    perceived[CRATE] = True  # perceived and held: never released here (Place is decided after physics)
    supported = np.array([[False] * 5, [True] * 5])
    new, codes = model.mechanism(ReleaseOnLoss).releases(modes, perceived, supported, np.random.default_rng(0))
    assert list(new[:, CUP]) == [FREE, FREE] and list(codes[:, CUP]) == [RELEASE, PLACE]
    assert list(new[:, BALL]) == [HELD, HELD] and list(new[:, CRATE]) == [HELD, HELD]
    assert np.all(modes[:, CUP] == HELD)  # input untouched


def _cup_held_seen_still(model, st, z, cup_boxes):
    """The cup seen still at height ``z`` (m) for 0.4 s, and the update's move; for
    :meth:`SceneModel.settle`, the cup HELD in both particles, whose physics put it in the boxes
    ``cup_boxes (2, 2, 3)`` (the table, crate and ball where ``scene()`` has them):
    ``(t, perceived, move, modes, out)``."""
    for i in range(13):  # 0.4 s still
        model.memory.record(Frame(i / 30, {"cup": Detection(np.array([0.3, 0.3, z]))}))
    t = 12 / 30
    perceived = model.memory.perceived(t)
    mv = model.move(st, Frame(t), perceived, perceived, 0.0, np.random.default_rng(0))
    modes = np.zeros((2, 5), np.int8)
    modes[:, CUP] = HELD
    aabbs = np.zeros((2, 5, 2, 3))
    aabbs[:, TABLE] = [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.1]]
    aabbs[:, CRATE] = [[-0.15, -0.1, 0.1], [0.15, 0.1, 0.22]]
    aabbs[:, BALL] = [[0.05, -0.03, 0.11], [0.11, 0.03, 0.17]]
    aabbs[:, CUP] = cup_boxes
    out = BatchOutput(st.poses.copy(), st.velocities.copy(), modes, np.zeros((2, 5)), aabbs, np.ones(2, bool),
                      np.zeros((2, 5)))
    return t, perceived, mv, modes, out


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
    t, perceived, mv, modes, out = _cup_held_seen_still(model, st, 0.14, [
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
    st2 = replace(st, modes=s.modes.copy(), holds=s.holds, supported=s.supported)
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
    t, perceived, mv, modes, out = _cup_held_seen_still(model, st, 0.15, [
        [[0.27, 0.27, 0.11], [0.33, 0.33, 0.19]],     # 1 cm above the table
        [[0.27, 0.27, 0.125], [0.33, 0.33, 0.205]]])  # 2.5 cm above it
    s = model.settle(st, replace(mv, modes=modes.copy()), out, t, 0.08, perceived, perceived)
    assert list(s.supported[:, CUP]) == [True, True]  # both within place_gap: supported
    assert list(s.modes[:, CUP]) == [FREE, HELD]


def test_an_object_physics_let_diverge_is_weighed_at_its_divergence_even_when_put_down_at_once():
    """A cup seen at rest, free in both particles: in particle 1 physics let it diverge 5 cm from its
    detection (the pool put it there and held it), and the update's Place rule lets it go again.
    The evidence still says it diverged, and the particle whose physics agreed weighs more: the
    override does not make particle 1's world look right."""
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    st = model.initial_state(np.random.default_rng(0))
    t, perceived, mv, _, _ = _cup_held_seen_still(model, st, 0.14, np.zeros((2, 2, 3)))
    assert mv.check[:, CUP].all() and np.all(mv.modes[:, CUP] == FREE)
    poses = st.poses.copy()
    poses[:, CUP, :3] = [0.3, 0.3, 0.14]  # both end on the detection
    modes = mv.modes.copy()
    modes[1, CUP] = HELD  # particle 1: switched by the divergence test
    divergence = np.zeros((2, 5))
    divergence[:, CUP] = [0.004, 0.05]
    aabbs = np.zeros((2, 5, 2, 3))
    aabbs[:, TABLE] = [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.1]]
    aabbs[:, CUP] = [[0.27, 0.27, 0.1], [0.33, 0.33, 0.18]]
    out = BatchOutput(poses, np.zeros_like(st.velocities), modes, divergence, aabbs, np.ones(2, bool),
                      np.zeros((2, 5)))
    settled = model.settle(st, mv, out, t, 0.08, perceived, perceived)
    assert list(settled.modes[:, CUP]) == [FREE, FREE]  # put down again at once
    assert list(out.modes[:, CUP]) == [FREE, HELD]      # what physics made is left as it was
    ev = model.evidence(mv, settled, out, Frame(t), perceived, perceived, st.unseen_in_view)
    assert np.isnan(ev.diverged[0, CUP]) and ev.diverged[1, CUP] == 0.05
    assert np.isnan(np.delete(ev.diverged, CUP, axis=1)).all()
    lw = model.log_weight(np.zeros(2), ev)
    assert lw[0] > lw[1] + 1.0


def test_log_weight_of_one_particle_is_only_the_explosion_mask():
    model = make(EstimatorConfig(particles=1, noise=NoiseConfig()))
    z = np.zeros((1, 5, 7))
    ev = Evidence(poses=z + 5.0, predicted=z, previous_modes=np.zeros((1, 5), np.int8),
                  modes=np.ones((1, 5), np.int8), detected=np.ones(5, bool), teleported=np.zeros(5, bool),
                  perceived=np.ones(5, bool), detected_poses=np.zeros((5, 7)), has_orientation=np.zeros(5, bool),
                  detection_std=np.full(5, 0.01), visible=np.ones((1, 5)), queried=np.ones(5, bool),
                  in_tracked_hand=np.zeros(5, bool), finite=np.ones(1, bool),
                  unseen_in_view=np.zeros((1, 5), np.int32))
    assert model.log_weight(np.zeros(1), ev)[0] == 0.0
    assert model.log_weight(np.zeros(1), replace(ev, finite=np.zeros(1, bool)))[0] == -np.inf
    two = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    ev2 = replace(ev, poses=np.concatenate([z, z + 5.0]), predicted=np.concatenate([z, z]),
                  previous_modes=np.zeros((2, 5), np.int8), modes=np.zeros((2, 5), np.int8),
                  visible=np.zeros((2, 5)), finite=np.ones(2, bool))
    lw = two.log_weight(np.zeros(2), ev2)
    assert lw[0] > lw[1] and np.all(np.isfinite(lw))  # with two, the detections weigh
    assert lw[0] == pytest.approx(sum(term(ev2)[0] for term in two.terms))


def test_regularisation_jitters_only_free_copies_of_hidden_objects():
    nz = NoiseConfig(regularisation=0.5, max_jitter_std=0.01, param_jitter=0.1)
    model = make(EstimatorConfig(particles=400, noise=nz))
    rng = np.random.default_rng(5)
    st = model.initial_state(rng)
    st.poses[:, BALL, :3] += rng.normal(0.0, 0.004, (400, 3))  # a spread to regularise
    st.modes[:50, BALL] = HELD
    w = np.full(400, 1 / 400)
    hidden = np.zeros(5, bool)
    hidden[[BALL, CUP]] = True
    kernels = regularisation_kernels(model, st.poses, w, hidden)
    assert set(kernels) == {BALL, CUP}
    hidden_ball = np.zeros(5, bool)
    hidden_ball[BALL] = True
    kernels = regularisation_kernels(model, st.poses, w, hidden_ball)
    cov = kernels[BALL] @ kernels[BALL].T
    assert np.sqrt(np.max(np.linalg.eigvalsh(cov))) <= 0.01 + 1e-12
    before = st.poses.copy()
    params = st.params.copy()
    regularise(model, st, kernels, np.random.default_rng(6))
    moved = np.any(st.poses != before, axis=-1)
    assert np.all(moved[50:, BALL]) and not moved[:50].any() and not moved[:, [CRATE, CUP]].any()
    assert np.array_equal(st.jolted[:, BALL], ~np.isin(np.arange(400), np.arange(50)))
    lo, hi = param_bounds(model.config)[:, 0], param_bounds(model.config)[:, 1]
    assert np.all((st.params >= lo) & (st.params <= hi)) and np.any(st.params != params)
    assert np.all(st.params[:, TABLE] == params[:, TABLE])


def test_a_hidden_objects_kernel_keeps_its_spread_when_the_weights_pick_one_particle():
    """Weights that leave one particle (about another object) size the kernel by the equal-weight
    spread mixed in at ``1 - ESS / K``: h^2 times that covariance, not the near-zero covariance of the
    one particle; with equal weights, h^2 times the covariance (Silverman-style kernel)."""
    nz = NoiseConfig(regularisation=0.5, max_jitter_std=1.0)
    model = make(EstimatorConfig(particles=400, noise=nz))
    rng = np.random.default_rng(8)
    st = model.initial_state(rng)
    st.poses[:, BALL, :3] += rng.normal(0.0, 0.004, (400, 3))
    hidden = np.zeros(5, bool)
    hidden[BALL] = True
    cov = np.cov(st.poses[:, BALL, :3].T, bias=True)
    even = regularisation_kernels(model, st.poses, np.full(400, 1 / 400), hidden)[BALL]
    assert np.allclose(even @ even.T, 0.25 * cov, rtol=1e-6, atol=1e-12)
    w = np.full(400, 1e-12)
    w[0] = 1.0
    w /= w.sum()
    one = regularisation_kernels(model, st.poses, w, hidden)[BALL]
    share = 1.0 / (400 * np.sum(w ** 2))
    mixed = share * w + (1.0 - share) / 400
    assert np.allclose(one @ one.T, 0.25 * np.cov(st.poses[:, BALL, :3].T, aweights=mixed, bias=True),
                       rtol=1e-6, atol=1e-12)
    assert np.trace(one @ one.T) > 0.9 * np.trace(even @ even.T)


def test_a_still_resting_object_takes_a_kalman_step_to_its_detection_and_a_moving_one_does_not():
    model = make(EstimatorConfig(particles=400, noise=NoiseConfig(process_position_std=0.0)))
    st = model.initial_state(np.random.default_rng(0))
    st.supported[:] = True
    mem = model.memory
    cup_at = np.array([0.3, 0.3, 0.14])
    for i in range(4):  # the cup, still, seen 1 cm off its particles' mean; the crate dragged away
        mem.record(Frame(0.1 * i, {"cup": Detection(cup_at + [0.01, 0.0, 0.0]),
                                    "crate": Detection(np.array([0.03 * i, 0.0, 0.16]))}))
    mem.end_tick(mem.perceived(0.3), np.ones(5, bool), mem.tick_velocity())
    mem.record(Frame(0.4, {"cup": Detection(cup_at + [0.01, 0.0, 0.0]),
                            "crate": Detection(np.array([0.12, 0.0, 0.16]))}))
    detected = np.zeros(5, bool)
    detected[[CRATE, CUP]] = True
    before = st.poses.copy()
    mv = model.move(st, Frame(0.4), detected, mem.perceived(0.4), 0.1, np.random.default_rng(1))
    # (a particle whose step would be under half a millimetre keeps its place: a few)
    assert mv.fused[:, CUP].mean() > 0.9 and not mv.fused[:, CRATE].any()  # the crate started moving
    assert np.array_equal(mv.poses[:, CRATE], before[:, CRATE]) and np.array_equal(mv.predicted, before)
    # the Kalman step's mean: prior mean + P / (P + R) (detection - prior mean), R = (1 cm)^2
    x0 = before[:, CUP, 0]
    p = x0.var() + 0.001 ** 2
    expect = x0.mean() + p / (p + 0.01 ** 2) * (cup_at[0] + 0.01 - x0.mean())
    sd = np.sqrt(p * 0.01 ** 2 / (p + 0.01 ** 2) / 400)
    assert abs(mv.poses[:, CUP, 0].mean() - expect) < 4 * sd
    assert np.array_equal(mv.poses[:, CUP, 2], before[:, CUP, 2])  # the height is physics's
    resting = np.ones((400, 5), bool)  # supported, at rest (zero velocities)
    # converged (the cloud's mean at the average still detection): no step, the object sleeps on
    st.poses[:, CUP, :2] = mem.still_position[CUP, :2] + np.random.default_rng(2).normal(0, 0.002, (400, 2))
    st.poses[:, CUP, :2] -= st.poses[:, CUP, :2].mean(axis=0) - mem.still_position[CUP, :2]
    fusion = model.mechanism(FusionAtRest)
    assert not fusion.fuse_resting(st.poses.copy(), st.log_weights, st.modes, resting, detected,
                                   np.random.default_rng(1))[:, CUP].any()
    off = make(EstimatorConfig(particles=400, noise=NoiseConfig(fuse_resting=False)))
    assert not any(isinstance(m, FusionAtRest) for m in off.mechanisms)  # off: not among the mechanisms


def test_round_objects_rolling_friction_is_scaled_log_uniformly_and_boxes_keep_theirs():
    sc = scene()
    cfg = EstimatorConfig(particles=4000, noise=NoiseConfig())
    memory = PerceptionMemory(sc, initial_poses(sc)[0], cfg.reasoner, cfg.follow_hands)
    base = np.tile([0.5, 0.002, 0.0, 0.1, 0.2], (len(sc.objects), 1))  # every object has one
    st = SceneModel(sc, cfg, base, memory).initial_state(np.random.default_rng(0))
    lo, hi = cfg.noise.rolling_friction_scale
    for m in (BALL, CUP, MYSTERY):  # sphere, cylinder, sphere
        f = np.log(st.params[:, m, 1] / 0.002)
        assert np.all((f >= np.log(lo) - 1e-12) & (f <= np.log(hi) + 1e-12))
        # log-uniform on [log lo, log hi]: mean 0 for (0.5, 2), std (log 4) / sqrt(12)
        sd = np.log(hi / lo) / np.sqrt(12)
        assert abs(f.mean() - np.log(lo * hi) / 2) < 3 * sd / np.sqrt(len(f))
    assert np.all(st.params[:, CRATE, 1] == 0.002) and np.all(st.params[:, TABLE, 1] == 0.002)
    fixed = EstimatorConfig(particles=50, noise=NoiseConfig(rolling_friction_range=(0.0, 0.001)))
    st = SceneModel(sc, fixed, base, memory).initial_state(np.random.default_rng(0))
    assert np.all(st.params[:, [CRATE, BALL], 1] <= 0.001)  # an absolute range replaces the scale


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


def test_a_held_object_that_leaves_view_rolling_is_let_go_at_its_fitted_velocity_with_its_standard_error():
    """A ball held in every particle is seen rolling along x at 0.3 m/s (3 mm detection noise along x), its last
    detection 2.5 cm short (that last pair reads under 0.2 m/s), then not: it left view moving and is
    let go in every particle, at the fitted line's velocity plus that velocity's standard error
    (mean within 3 standard errors of the fit, spread inside a chi-square band), spinning as it rolls."""
    K = 400
    model = make(EstimatorConfig(particles=K, noise=NoiseConfig(position_std=0.01)))
    st = model.initial_state(np.random.default_rng(0))
    st.modes[:, BALL] = HELD
    st.supported[:, BALL] = True  # on the table
    st.velocities[:, BALL] = [0.15, 0.0, 0.0, 0.0, 0.0, 0.0]
    mem, noise = model.memory, np.random.default_rng(1)
    detected = np.zeros(5, bool)
    detected[BALL] = True
    for j, t in enumerate([0.1, 0.2, 0.3, 0.4]):
        for f in range(3):
            tf = t + f / 30
            x = 0.08 + 0.3 * (tf - 0.1) - (0.025 if (t, f) == (0.4, 2) else 0.0)
            pos = np.array([x, 0.0, 0.14]) + noise.normal(0.0, 0.003, 3) * [1, 0, 0]
            mem.record(Frame(tf, {"ball": Detection(pos, position_std=0.003)}))
        perceived = mem.perceived(t + 2 / 30)
        mem.end_tick(perceived, detected, mem.tick_velocity())
    assert np.isfinite(mem.moving_since[BALL])
    assert np.linalg.norm(mem.previous_tick_velocity()[BALL, :2]) < 0.2 < np.linalg.norm(mem.perc_vel[BALL, :2])
    frame = Frame(0.5 + 2 / 30)
    perceived = mem.perceived(frame.t)
    assert perceived[BALL]
    mv = model.move(st, frame, np.zeros(5, bool), perceived, 0.1, np.random.default_rng(2))
    assert np.all(mv.modes[:, BALL] == FREE)
    fit, se = mem.perc_vel[BALL, 0], mem.velocity_std(0.01)[BALL]
    assert se > 0
    vx = mv.velocities[:, BALL, 0]
    assert abs(vx.mean() - fit) < 3 * se / math.sqrt(K)
    lo, hi = (K - 1 - 3 * math.sqrt(2 * (K - 1))) / (K - 1), (K - 1 + 3 * math.sqrt(2 * (K - 1))) / (K - 1)
    assert lo < vx.var(ddof=1) / se ** 2 < hi
    assert np.allclose(mv.velocities[:, BALL, 4], vx / 0.03)  # w_y = v_x / r: rolling
