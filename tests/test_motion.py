"""estimator.model.motion alone, on hand-built arrays: teleport kinds, placing, rolling spin, reach, let-goes."""
import math

import numpy as np
import pytest

from actions.modes import FREE, HELD, ModePriors
from estimator.config import NoiseConfig
from estimator.model.likelihood import mode_switch_log_prior
from estimator.model.motion import (
    let_go_moving,
    out_of_reach,
    place,
    roll_released,
    rolled_along,
    rolling_spin,
    teleport_kinds,
)


def test_rolled_along_means_faster_than_the_threshold_horizontally_and_slower_vertically():
    vel = np.array([[0.5, 0.0, 0.0], [0.1, 0.1, 0.0], [0.5, 0.0, -0.5], [0.0, -0.3, 0.1]])
    assert rolled_along(vel).tolist() == [True, False, False, True]


def test_teleport_kinds_split_rolling_along_from_rolling_off_an_edge():
    tracked = np.array([True, True, True, True, False])
    now = np.array([[0.9, 0, 0], [0.9, 0, -0.8], [0.05, 0, -0.9], [0.0, 0, 0.0], [0.9, 0, 0]])
    before = np.array([[0.9, 0, 0], [0.9, 0, 0], [0.05, 0, -0.5], [0.0, 0, 0.0], [0.9, 0, 0]])
    moving, falling = teleport_kinds(tracked, now, before)
    assert moving.tolist() == [True, False, False, True, False]   # level now (at rest counts: zero velocity)
    assert falling.tolist() == [False, True, False, False, False]  # falling now, rolling along before


def test_place_puts_objects_at_the_given_positions_with_noise_except_where_held():
    K, M = 3000, 2
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    vel = np.zeros((K, M, 6))
    vel[:, 0, 3:] = [1.0, 2.0, 3.0]  # each particle's spin before
    held = np.zeros((K, M), bool)
    held[:10, 0] = True
    positions = np.array([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0]])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (M, 1))
    perc_vel = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    drawn = place(poses, vel, np.array([0]), np.zeros(M, bool), np.zeros((K, M, M), bool), positions, quat,
                  np.zeros(M, bool), perc_vel, NoiseConfig(position_std=0.01), np.random.default_rng(0),
                  spinning=np.array([True, False]), held=held, ball_radius=np.array([np.nan, np.nan]))
    assert drawn.shape == (K, 1, 3) and np.all(drawn[:10] == 0)
    assert np.allclose(poses[:, 0, :3] - drawn[:, 0], positions[0])
    sd = drawn[10:, 0].std(axis=0)  # 1 cm per axis within its 3-sigma band (chi-square, n large)
    assert np.all(np.abs(sd - 0.01) < 3 * 0.01 / math.sqrt(2 * (K - 10)))
    assert np.allclose(vel[:, 0, :3], [0.5, 0.0, 0.0]) and np.all(vel[:, 0, 3:] == [1.0, 2.0, 3.0])  # spin kept
    assert np.all(poses[:, 1] == [0, 0, 0, 0, 0, 0, 1])  # not teleported


def test_a_teleported_container_carries_its_contents_and_a_held_one_leaves_them_their_velocity():
    """A box (object 0) with a ball in it (object 1) is teleported 5 cm along x at 0.3 m/s, in
    particle 0 free (the ball takes the box's velocity: they were put there together) and in
    particle 1 held (it glides on to its target: the ball keeps its own velocity, lags and rolls as
    the contact solver says; not in paper mode, which passes no ``gliding``). In both the ball
    moves rigidly with the box."""
    K, M = 2, 2
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    poses[:, 1, :3] = [0.02, 0.0, 0.03]
    vel = np.zeros((K, M, 6))
    vel[:, 1, :3] = [-0.1, 0.05, 0.0]  # the ball rolls in the box
    is_in = np.zeros((K, M, M), bool)
    is_in[:, 1, 0] = True
    held = np.array([[False, False], [True, False]])
    positions = np.array([[0.05, 0.0, 0.0], [0.0, 0.0, 0.0]])
    place(poses, vel, np.array([0]), np.zeros(M, bool), is_in, positions, np.tile([0.0, 0.0, 0.0, 1.0], (M, 1)),
          np.zeros(M, bool), np.array([[0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]), NoiseConfig.off(), np.random.default_rng(0),
          held=held, gliding=held)
    assert np.allclose(poses[:, 1, :3], [0.07, 0.0, 0.03])
    assert np.allclose(vel[0, 1, :3], [0.3, 0.0, 0.0]) and np.allclose(vel[1, 1, :3], [-0.1, 0.05, 0.0])
    vel[:, 1, :3] = [-0.1, 0.05, 0.0]
    place(poses, vel, np.array([0]), np.zeros(M, bool), is_in, positions, np.tile([0.0, 0.0, 0.0, 1.0], (M, 1)),
          np.zeros(M, bool), np.zeros((M, 3)), NoiseConfig.off(), np.random.default_rng(0), held=held)
    assert np.all(vel[:, 1, :3] == 0.0)  # paper mode: teleported at rest, contents too



def test_each_particle_carries_only_what_its_own_containers_hold():
    """Two boxes (objects 0 and 1) teleported at once, 5 cm and 10 cm along x; what is in them
    differs per particle: in particle 0 the ball (2) is in box 0, in particle 1 the cube (3) is in
    box 1 and the ball in box 0, in particle 2 nothing is in anything. A teleported object is
    never carried (box 1 in box 0 in particle 2 stays where its own teleport puts it). Each content
    moves with its own particle's container, and only there."""
    K, M = 3, 4
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    poses[:, 2, :3] = [0.01, 0.0, 0.02]
    poses[:, 3, :3] = [0.5, 0.0, 0.02]
    vel = np.zeros((K, M, 6))
    is_in = np.zeros((K, M, M), bool)
    is_in[0, 2, 0] = True
    is_in[1, 2, 0] = is_in[1, 3, 1] = True
    is_in[2, 1, 0] = True
    positions = np.array([[0.05, 0.0, 0.0], [0.6, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    poses[:, 1, :3] = [0.5, 0.0, 0.0]
    gliding = np.zeros((K, M), bool)
    gliding[1, 1] = True  # box 1 held in particle 1: the cube keeps its velocity
    vel[:, 3, :3] = [0.0, 0.2, 0.0]
    perc_vel = np.array([[0.3, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    place(poses, vel, np.array([0, 1]), np.zeros(M, bool), is_in, positions, np.tile([0.0, 0.0, 0.0, 1.0], (M, 1)),
          np.zeros(M, bool), perc_vel, NoiseConfig.off(), np.random.default_rng(0), gliding=gliding)
    assert np.allclose(poses[:, 0, :3], [0.05, 0.0, 0.0]) and np.allclose(poses[:, 1, :3], [0.6, 0.0, 0.0])
    assert np.allclose(poses[[0, 1], 2, :3], [0.06, 0.0, 0.02]) and np.allclose(poses[2, 2, :3], [0.01, 0.0, 0.02])
    assert np.allclose(poses[1, 3, :3], [0.6, 0.0, 0.02]) and np.allclose(poses[[0, 2], 3, :3], [0.5, 0.0, 0.02])
    assert np.allclose(vel[[0, 1], 2, :3], [0.3, 0.0, 0.0]) and np.all(vel[2, 2] == 0.0)
    assert np.allclose(vel[:, 3, :3], [0.0, 0.2, 0.0])  # carried while gliding in particle 1, elsewhere not at all
    assert np.allclose(vel[:, 1, :3], [0.0, 0.4, 0.0])  # teleported itself: its own perceived velocity

def test_objects_teleported_in_motion_get_their_velocity_error_per_particle():
    """``vel_std`` (m/s) spreads the horizontal velocity of objects teleported in motion, per axis
    within the chi-square 3-sigma band of 4000 particles, around the perceived velocity (mean within
    3 standard errors); the vertical velocity, objects at rest and paper mode (no vel_std) get none;
    a ball's spin follows its own drawn velocity."""
    K, M = 4000, 2
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    vel = np.zeros((K, M, 6))
    positions = np.zeros((M, 3))
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (M, 1))
    perc_vel = np.array([[0.5, -0.2, 0.0], [0.0, 0.0, 0.0]])
    std = np.array([0.05, 0.05])
    place(poses, vel, np.array([0, 1]), np.zeros(M, bool), np.zeros((K, M, M), bool), positions, quat,
          np.zeros(M, bool), perc_vel, NoiseConfig(position_std=0.01), np.random.default_rng(2),
          spinning=np.array([True, False]), ball_radius=np.array([0.03, np.nan]), vel_std=std)
    sd = vel[:, 0, :2].std(axis=0)
    assert np.all(np.abs(sd - 0.05) < 3 * 0.05 / math.sqrt(2 * K))
    assert np.all(np.abs(vel[:, 0, :2].mean(axis=0) - perc_vel[0, :2]) < 3 * 0.05 / math.sqrt(K))
    assert np.all(vel[:, 0, 2] == 0) and np.all(vel[:, 1] == 0)
    assert np.allclose(vel[:, 0, 3:5], np.stack([-vel[:, 0, 1], vel[:, 0, 0]], axis=1) / 0.03)
    again = np.zeros((K, M, 6))
    place(poses, again, np.array([0]), np.zeros(M, bool), np.zeros((K, M, M), bool), positions, quat,
          np.zeros(M, bool), perc_vel, NoiseConfig(position_std=0.01), np.random.default_rng(2),
          spinning=np.array([True, False]), ball_radius=np.array([0.03, np.nan]))
    assert np.allclose(again[:, 0, :3], perc_vel[0])


def test_a_ball_given_a_velocity_spins_as_it_rolls_and_other_shapes_keep_their_spin():
    radius = np.array([0.03, np.nan])
    vel = np.zeros((2, 2, 6))
    vel[:, 0, :3] = [0.3, -0.6, 0.0]
    vel[:, 1] = [0.3, 0.0, 0.0, 1.0, 2.0, 3.0]
    rolling_spin(vel, np.array([0, 1]), radius, np.array([True, False]))
    assert np.allclose(vel[0, 0, 3:], np.cross([0, 0, 1], [0.3, -0.6, 0.0]) / 0.03)
    contact = vel[0, 0, :3] + np.cross(vel[0, 0, 3:], [0, 0, -0.03])
    assert np.allclose(contact, 0.0)  # rolling without slipping: the contact point is at rest
    assert np.all(vel[1, 0, 3:] == 0) and np.all(vel[:, 1, 3:] == [1.0, 2.0, 3.0])
    released = np.array([[False, True], [True, True]])
    roll_released(vel, released, radius)
    assert np.allclose(vel[1, 0, 3:], vel[0, 0, 3:]) and np.all(vel[:, 1, 3:] == [1.0, 2.0, 3.0])


def test_out_of_reach_of_every_tracked_hand():
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    hands = {"left": np.array([0.1, 0.0, 0.0]), "right": np.array([2.2, 0.0, 0.0])}
    assert out_of_reach(pos, hands, np.array([True, True, True]), 0.3).tolist() == [False, True, False]
    assert out_of_reach(pos, hands, np.array([True, False, True]), 0.3).tolist() == [False, False, False]
    assert out_of_reach(pos, {}, np.ones(3, bool), 0.3) is None


def _held_ball(K):
    modes = np.zeros((K, 2), np.int8)
    modes[:, 1] = HELD
    rolling = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    return modes, np.ones((K, 2), bool), np.array([False, True]), rolling


def test_let_go_in_motion_is_proposed_at_its_rate_and_weighed_back_to_the_prior():
    K = 4000
    modes, supported, cand, rolling = _held_ball(K)
    let, logw = let_go_moving(modes, supported, cand, rolling, 0.2, np.random.default_rng(3))
    assert not let[:, 0].any()
    n = int(let[:, 1].sum())
    assert abs(n - 0.2 * K) < 3 * math.sqrt(K * 0.2 * 0.8)  # binomial band
    assert logw == pytest.approx(np.where(let[:, 1], -math.log(0.2), -math.log(0.8)))
    # with the switch's prior (place 0.2, the mode-switch term's) every particle weighs the same
    new = modes.copy()
    new[let] = FREE
    priors = ModePriors()
    assert np.allclose(logw + mode_switch_log_prior(priors, modes, new, cand), 0.0)
    # at another rate they are importance weights: their mean is 1 within its 3-sigma band
    let5, logw5 = let_go_moving(modes, supported, cand, rolling, 0.5, np.random.default_rng(4))
    new5 = modes.copy()
    new5[let5] = FREE
    w = np.exp(logw5 + mode_switch_log_prior(priors, modes, new5, cand))
    assert np.mean(w) == pytest.approx(1.0, abs=3 * np.std(w) / math.sqrt(K))


@pytest.mark.parametrize("velocity", [[0.5, 0.0, -1.0], [0.1, 0.0, 0.0]])
def test_no_let_go_in_motion_when_falling_or_slow_or_never_tried(velocity):
    modes, supported, cand, rolling = _held_ball(50)
    rolling[1] = velocity
    let, logw = let_go_moving(modes, supported, cand, rolling, 0.2, np.random.default_rng(3))
    assert not let.any() and np.all(logw == 0)
    modes, supported, cand, rolling = _held_ball(50)
    let, logw = let_go_moving(modes, supported, cand, rolling, 0.0, np.random.default_rng(3))
    assert not let.any() and np.all(logw == 0)


def test_drop_heights_measure_the_fall_to_the_highest_top_under_the_footprint():
    from estimator.model.motion import drop_heights

    # particle 0: a cup (object 1) 5 cm over a table top (object 0, top at 0.6); particle 1: the same
    # cup beside the table, 0.7 m over the floor; object 2, a box beside the cup, never counts
    aabbs = np.zeros((2, 3, 2, 3))
    aabbs[:, 0] = [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.6]]
    aabbs[0, 1] = [[0.0, 0.0, 0.65], [0.08, 0.08, 0.75]]
    aabbs[1, 1] = [[0.7, 0.0, 0.7], [0.78, 0.08, 0.8]]
    aabbs[:, 2] = [[0.2, 0.2, 0.0], [0.3, 0.3, 0.9]]
    kk, mm = np.array([0, 1]), np.array([1, 1])
    assert np.allclose(drop_heights(aabbs, kk, mm, np.zeros(2), floor=True), [0.05, 0.7])
    # let go 3 cm higher than where it is now (it fell that far during the update)
    assert np.allclose(drop_heights(aabbs, kk, mm, np.full(2, 0.03), floor=True), [0.08, 0.73])
    # no floor: nothing under the cup beside the table
    assert np.isinf(drop_heights(aabbs, kk, mm, np.zeros(2), floor=False)[1])
    # sunk 3 cm into its support (held into it): no fall, and not through to the floor
    aabbs[0, 1, :, 2] = [0.57, 0.67]
    assert drop_heights(aabbs, kk[:1], mm[:1], np.zeros(1), floor=True)[0] == 0.0
