"""Release on loss: estimator.model.mechanisms.release."""
import math

import numpy as np

from actions.modes import FREE, HELD, PLACE, RELEASE, ModePriors
from estimator.config import EstimatorConfig, NoiseConfig, ReasonerConfig
from estimator.model import initial_poses
from estimator.model.mechanisms.release import ReleaseOnLoss, release_on_loss
from estimator.model.perception_memory import PerceptionMemory
from estimator.observations import Detection, Frame
from model_helpers import BALL, CRATE, CUP, make
from physics.scene import scene_from_dict


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


def test_a_held_object_that_leaves_view_in_motion_is_let_go_in_every_particle():
    """Seen moving along its support at the last update, undetected now, no tracked hand (``left_view``):
    every particle that holds it lets it go, though it still counts as perceived; the switch is a
    Place (on a support); without ``left_view`` nothing is let go while perceived."""
    K = 100
    modes = np.full((K, 1), HELD, np.int8)
    modes[:10] = FREE
    mem = _memory([0.1, 0.0, 0.78])
    supported = np.ones((K, 1), bool)
    new, codes = release_on_loss(modes, np.array([True]), supported, np.random.default_rng(5), mem, ModePriors(),
                                 None, np.array([True]))
    assert np.all(new == FREE) and np.all(codes[10:] == PLACE) and np.all(codes[:10] == 0)
    kept, _ = release_on_loss(modes, np.array([True]), supported, np.random.default_rng(5), mem, ModePriors(), None,
                              np.array([False]))
    assert np.array_equal(kept, modes)
