"""Following a hand: estimator.model.mechanisms.follow_hand (held objects' targets)."""
import math

import numpy as np
import pytest

from actions.modes import HELD, is_held
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.follow_hand import FollowHands
from estimator.observations import Detection, Frame
from model_helpers import CUP, make


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
    from estimator.worlds.held import hand_offset_walk
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
    # seen still (no motion onset) and held in no particle: the hand near it does not carry it (a
    # tray a mug was just put in); held in some particle, or seen moving, it does
    assert np.isnan(mem.moving_since[CUP])
    assert not (mem.stale_in_hand(later, none) & detected).any()
    assert np.flatnonzero(mem.stale_in_hand(later, is_held(modes).any(axis=0)) & detected).tolist() == [CUP]
    mem.moving_since[CUP] = 1.0  # seen moving since 1.0 s
    assert np.flatnonzero(mem.stale_in_hand(later, none) & detected).tolist() == [CUP]
    stale = mem.stale_in_hand(later, is_held(modes).any(axis=0)) & detected  # as the model's move computes them
    target, _, err = model.mechanism(FollowHands).held_targets(later, st.poses, modes, detected, detected, 0.1, np.random.default_rng(3),
                                        before, None, None, mem.detections_now(stale, later.t), stale)
    np.testing.assert_allclose(err[:, CUP], expect)
    np.testing.assert_allclose(target[:, CUP, :3], np.array([1.0, 0.0, 0.95]) + moved + expect)


@pytest.mark.parametrize("average", [False, True])
def test_a_still_object_not_detected_in_the_update_stays_where_it_was_seen_still(average):
    """With moving teleports, a perceived object not detected in this update is carried on at its
    fitted velocity only if seen moving (a motion onset): a still object's fitted velocity is its
    detections' noise, which would carry its target away (a tray lifted 5 cm by 1 cm of noise). It
    stays at its last detection, or with ``still_average`` at the average of its still ones."""
    model = make(EstimatorConfig(particles=2, follow_hands=False, moving_teleports=True,
                                 noise=NoiseConfig(still_average=average)))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    for t, z in [(0.0, 0.300), (0.033, 0.306), (0.067, 0.298), (0.1, 0.309)]:
        mem.record(Frame(t, {"cup": Detection(np.array([0.3, 0.3, z]))}))
    assert np.isnan(mem.moving_since[CUP]) and mem.perc_vel[CUP, 2] > 0.02  # noise fits a velocity
    perceived, none = mem.perceived(0.3), np.zeros(5, bool)
    assert perceived[CUP]
    follow = model.mechanism(FollowHands)
    target, target_vel, _ = follow.held_targets(Frame(0.3), st.poses, st.modes, none, perceived, 0.2,
                                                np.random.default_rng(0), st.hold_error, none)
    z = (0.300 + 0.306 + 0.298 + 0.309) / 4 if average else 0.309
    np.testing.assert_allclose(target[:, CUP, :3], [[0.3, 0.3, z]] * 2)
    assert np.all(target_vel[:, CUP] == 0.0)


def test_a_still_object_is_tested_against_the_average_of_its_still_detections():
    """``NoiseConfig.still_average``: a detected object seen still has, in every particle where it is
    free, the average of its still detections as its target (a resting mug under 1 cm of noise is
    not overridden by the one detection in a few dozen that lies 4.5 cm from where the particles
    have it); where it is held, its latest detection (the hand has it there: a box held still for a
    pour turns about its centre); once a detection says it moved, its latest detection everywhere.
    Without it, the latest detection throughout."""
    rng = np.random.default_rng(11)
    for average in (True, False):
        model = make(EstimatorConfig(particles=3, follow_hands=False, moving_teleports=True,
                                     noise=NoiseConfig(still_average=average)))
        st = model.initial_state(np.random.default_rng(0))
        mem, follow = model.memory, model.mechanism(FollowHands)
        rest = np.array([0.2, -0.1, 0.45])
        seen = rest + rng.normal(0.0, 0.003, (12, 3))  # 3 mm: none is a motion onset (1.5 cm)
        for i, p in enumerate(seen):
            mem.record(Frame(i / 30, {"cup": Detection(p)}))
        assert np.isnan(mem.moving_since[CUP])
        modes = st.modes.copy()
        modes[0, CUP] = HELD  # held in particle 0, free in the others
        det = np.zeros(5, bool)
        det[CUP] = True
        target, target_vel, _ = follow.held_targets(Frame(11 / 30), st.poses, modes, det, mem.perceived(11 / 30), 0.1,
                                                    np.random.default_rng(0), st.hold_error, np.zeros(5, bool))
        expect = seen.mean(axis=0) if average else seen[-1]
        np.testing.assert_allclose(target[1:, CUP, :3], [expect] * 2, atol=1e-12)
        np.testing.assert_allclose(target[0, CUP, :3], seen[-1])
        assert np.all(target_vel[:, CUP] == 0.0)
        # the cup moves: 10 cm away is a motion onset, and the target is that detection
        moved = rest + [0.1, 0.0, 0.0]
        mem.record(Frame(12 / 30, {"cup": Detection(moved)}))
        assert np.isfinite(mem.moving_since[CUP])
        target, _, _ = follow.held_targets(Frame(12 / 30), st.poses, modes, det, mem.perceived(12 / 30), 0.1,
                                           np.random.default_rng(0), st.hold_error, np.zeros(5, bool))
        np.testing.assert_allclose(target[:, CUP, :3], [moved] * 3)
