"""Fusion at rest: estimator.model.mechanisms.rest_fusion."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.rest_fusion import FusionAtRest
from estimator.observations import Detection, Frame
from model_helpers import CRATE, CUP, make


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


def test_a_resting_object_let_go_at_one_detection_moves_whole_to_where_its_detections_average():
    """Every particle has the cup at the one detection it was let go at, 2.4 cm from where the
    detections since average: a Kalman step would move it by its floor's gain (1 mm of prior spread
    against 1 cm of noise: 1 %, under the half-millimetre minimum); it moves whole, every particle by
    the same shift, so that none is weighed against another for it."""
    model = make(EstimatorConfig(particles=64, noise=NoiseConfig(process_position_std=0.0)))
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    rest = np.array([0.3, 0.3, 0.14])
    seen = rest + np.random.default_rng(5).normal(0.0, 0.003, (9, 3))
    for i, p in enumerate(seen):
        mem.record(Frame(0.1 * i, {"cup": Detection(p)}))
    assert np.isnan(mem.moving_since[CUP])
    st.poses[:, CUP, :3] = rest + [0.024, 0.0, 0.0]  # let go there, in every particle
    resting, detected = np.ones((64, 5), bool), np.zeros(5, bool)
    detected[CUP] = True
    poses = st.poses.copy()
    moved = model.mechanism(FusionAtRest).fuse_resting(poses, st.log_weights, st.modes, resting, detected,
                                                       np.random.default_rng(1))
    assert moved[:, CUP].all()
    np.testing.assert_allclose(poses[:, CUP, :2], np.broadcast_to(mem.still_position[CUP, :2], (64, 2)))
    assert np.all(poses[:, CUP, 2] == st.poses[:, CUP, 2])  # the height is physics's


def test_a_cloud_with_no_spread_moves_only_when_the_average_says_it_is_significantly_off():
    """The average of n still detections has a standard error of the detection noise over the
    square root of n: a cloud with no spread 4 mm from it stays where it is while the average is
    too noisy to tell (4 detections: 3 standard errors are 3 x 5 mm / 2 = 7.5 mm), and moves once
    the average is sure of it (36 detections: 2.5 mm), every particle by the same shift; meanwhile
    only the Kalman step moves it, by its small gain."""
    nz = NoiseConfig(process_position_std=0.0, position_std=0.005)
    model = make(EstimatorConfig(particles=64, noise=nz))
    st = model.initial_state(np.random.default_rng(0))
    mem, fusion = model.memory, model.mechanism(FusionAtRest)
    rest = np.array([0.3, 0.3, 0.14])
    resting, detected = np.ones((64, 5), bool), np.zeros(5, bool)
    detected[CUP] = True
    for i in range(36):
        mem.record(Frame(0.1 * i, {"cup": Detection(rest + [0.0, 0.0, 0.0])}))
        if mem.still_count[CUP] not in (4, 36):
            continue
        st.poses[:, CUP, :3] = mem.still_position[CUP] + [0.004, 0.0, 0.0]  # one point in every particle
        poses = st.poses.copy()
        moved = fusion.fuse_resting(poses, st.log_weights, st.modes, resting, detected, np.random.default_rng(1))
        if mem.still_count[CUP] == 4:  # (the Kalman step's gain, 1 mm of floor against 5 mm: 4 %)
            assert abs(poses[:, CUP, 0].mean() - st.poses[0, CUP, 0]) < 1e-3
        else:
            assert moved[:, CUP].all()
            np.testing.assert_allclose(poses[:, CUP, :2], np.broadcast_to(mem.still_position[CUP, :2], (64, 2)))
