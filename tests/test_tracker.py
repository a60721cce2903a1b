"""The physics-aware Kalman tracker: equivalence with plain filterpy, consistency (NEES), gating,
feedback from a belief, time checks."""
import dataclasses
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.stats import chi2

from estimator.applications.tracker import H_POS, PhysicsAwareTracker, TrackerConfig
from estimator.belief import Belief, ObjectBelief, region_radius_sq
from estimator.model.hands import process_noise, transition
from estimator.observations import Detection, Frame

DT = 1 / 30


def frame(t, **positions):
    return Frame(t, {oid: Detection(np.asarray(p, float), np.array([0, 0, 0, 1.0]), std)
                     for oid, (p, std) in positions.items()})


def belief(t, **objects):
    """A hand-built belief: ``objects[id] = (position (3,), covariance (3, 3))``."""
    obs = {oid: ObjectBelief(np.asarray(p, float), np.array([0, 0, 0, 1.0]), np.asarray(c, float), 0.0,
                             False, 1.0, 0.0) for oid, (p, c) in objects.items()}
    return Belief(t, obs, [], [], 1.0)


def simulate_cv(rng, n, accel_std, meas_std, vel_std):
    """Truth states ``(n, 6)`` of a constant-velocity model with white acceleration, and measurements
    ``(n, 3)``; the initial state is distributed as the tracker's initial belief."""
    f, q = transition(DT), process_noise(DT, accel_std)
    x = np.zeros((n, 6))
    x[0, 3:] = rng.normal(0.0, vel_std, 3)
    for k in range(1, n):
        x[k] = f @ x[k - 1] + rng.multivariate_normal(np.zeros(6), q)
    z = x[:, :3] + rng.normal(0.0, meas_std, (n, 3))
    return x, z


def test_feedback_off_equals_plain_filterpy():
    cfg = TrackerConfig(use_feedback=False, accel_std=1.5, measurement_std=0.02, velocity_std=0.7)
    rng = np.random.default_rng(1)
    x, z = simulate_cv(rng, 40, cfg.accel_std, cfg.measurement_std, cfg.velocity_std)
    trk = PhysicsAwareTracker(cfg)
    r = cfg.measurement_std ** 2 * np.eye(3)
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x = np.r_[z[0], np.zeros(3)].reshape(6, 1)
    kf.P = np.diag([cfg.measurement_std ** 2] * 3 + [cfg.velocity_std ** 2] * 3)
    kf.F, kf.Q, kf.H, kf.R = transition(DT), process_noise(DT, cfg.accel_std), H_POS, r
    for k in range(40):
        t = k * DT
        # a belief claiming something else must change nothing when feedback is off
        out = trk.update(frame(t, cup=(z[k], None)))
        assert trk.feedback(belief(t, cup=(z[k] + 1.0, np.eye(3)))) == []
        if k > 0:
            kf.predict()
            kf.update(z[k])
            assert out.action["cup"] == "accepted"
        tr = trk.tracks["cup"]
        np.testing.assert_allclose(tr.kf.x, kf.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr.kf.P, kf.P, rtol=0, atol=1e-12)


def test_nees_in_chi_square_band():
    """N independent runs on a linear-Gaussian stream: the mean NEES at the last step (full state,
    d = 6, and position, d = 3) lies in the two-sided 95 % chi-square band."""
    cfg = TrackerConfig(accel_std=2.0, measurement_std=0.01, velocity_std=0.5)
    rng = np.random.default_rng(7)
    n_runs, n_steps = 100, 30
    full, pos = [], []
    for _ in range(n_runs):
        x, z = simulate_cv(rng, n_steps, cfg.accel_std, cfg.measurement_std, cfg.velocity_std)
        trk = PhysicsAwareTracker(cfg)
        for k in range(n_steps):
            out = trk.update(frame(k * DT, ball=(z[k], None)))
        assert out.action["ball"] == "accepted"
        kf = trk.tracks["ball"].kf
        e = x[-1] - kf.x[:, 0]
        full.append(e @ np.linalg.solve(kf.P, e))
        pos.append(trk.nees("ball", x[-1, :3]))
    for values, d in ((full, 6), (pos, 3)):
        lo, hi = chi2.ppf([0.025, 0.975], n_runs * d) / n_runs
        assert lo <= np.mean(values) <= hi, (d, np.mean(values), lo, hi)


def test_gate_rejects_five_sigma_accepts_one_sigma():
    cfg = TrackerConfig(measurement_std=0.01)
    for n_sigma, expected in ((5.0, "rejected"), (1.0, "accepted")):
        trk = PhysicsAwareTracker(cfg)
        for k in range(10):
            trk.update(frame(k * DT, cup=([0.0, 0.0, 0.7], None)))
        t = 10 * DT
        trk.predict(t)
        r = cfg.measurement_std ** 2 * np.eye(3)
        s = (H_POS @ trk.tracks["cup"].kf.P @ H_POS.T + r)[0, 0]
        z = np.array([n_sigma * np.sqrt(s), 0.0, 0.7])
        out = trk.update(frame(t, cup=(z, None)))
        assert out.action["cup"] == expected
        assert out.d2["cup"] == pytest.approx(n_sigma ** 2, rel=1e-9)
        assert trk.rejections == (1 if expected == "rejected" else 0)


def test_persistent_jump_reinitialises_after_reinit_time():
    cfg = TrackerConfig(reinit_after=0.2)
    trk = PhysicsAwareTracker(cfg)
    trk.update(frame(0.0, cup=([0, 0, 0.7], None)))
    actions = [trk.update(frame(k * DT, cup=([0.5, 0, 0.7], None))).action["cup"] for k in range(1, 10)]
    assert actions[0] == "rejected" and "reinitialised" in actions
    np.testing.assert_allclose(trk.tracks["cup"].position, [0.5, 0, 0.7], atol=0.01)


def test_unseen_track_coasts_then_is_dropped_without_feedback():
    trk = PhysicsAwareTracker(TrackerConfig(coast_time=0.5, use_feedback=False))
    for k in range(10):
        trk.update(frame(k * DT, cup=([0.1 * k * DT, 0, 0.7], None)))
    trk.update(frame(0.6, ))
    assert "cup" in trk.tracks and trk.tracks["cup"].position[0] > 0.05  # constant-velocity prediction
    trk.update(frame(0.3 + 0.5 + 0.01))
    assert "cup" not in trk.tracks


def test_feedback_follows_belief_with_honest_covariance():
    # a constant-velocity model with a 2 m/s^2 white acceleration cannot follow a free fall: the
    # pseudo-measurements leave its gate (at the default 5 m/s^2 they may not)
    trk = PhysicsAwareTracker(TrackerConfig(coast_time=0.5, pseudo_fusion="kalman", accel_std=2.0),
                              object_ids=("ball", "cup"))
    for k in range(10):
        trk.update(frame(k * DT, ball=([0.2, 0.0, 0.7], None)))
    # hidden: physics says the ball falls off the table; its covariance grows
    t, stds = 10 * DT, []
    for k in range(40):
        t = (10 + k) * DT
        trk.update(frame(t))
        std = 0.01 + 0.002 * k
        z = np.array([0.2, 0.0, max(0.7 - 0.5 * 9.81 * (k * DT) ** 2, 0.03)])
        pm_cov = std ** 2 * np.eye(3)
        assert trk.feedback(belief(t, ball=(z, pm_cov))) == ["ball"]
        tr = trk.tracks["ball"]
        r = pm_cov + trk.config.pseudo_std_floor ** 2 * np.eye(3)
        # within 3 sigma of the pseudo-measurement, and no more confident than it
        e = tr.position - z
        assert e @ np.linalg.solve(r, e) < chi2.ppf(0.99, 3)
        assert np.all(np.linalg.eigvalsh(r - tr.position_cov) >= -1e-12)
        stds.append(tr.position_std)
    assert t > 1.0 and "ball" in trk.tracks  # alive far beyond coast_time
    assert trk.pseudo_resets >= 1  # the fall is beyond the constant-velocity model: restarted at the belief
    assert stds[-1] > 2 * stds[5]  # the track's spread grows with the belief's
    np.testing.assert_allclose(trk.tracks["ball"].position, [0.2, 0.0, 0.03], atol=0.02)
    # an object never detected but in the belief starts a track; a detected one is left alone
    trk.update(frame(t + DT, ball=([0.2, 0.0, 0.03], 0.01)))
    done = trk.feedback(belief(t + DT, ball=([5, 5, 5], np.eye(3)), cup=([0.3, 0.1, 0.7], 1e-4 * np.eye(3)),
                               table=([0, 0, 0], np.zeros((3, 3)))))
    assert done == ["cup"] and "table" not in trk.tracks
    np.testing.assert_allclose(trk.tracks["ball"].position, [0.2, 0.0, 0.03], atol=0.02)
    fr = trk.to_frame()
    assert set(fr.objects) == {"ball", "cup"} and fr.t == pytest.approx(t + DT)
    assert fr.objects["cup"].position_std == pytest.approx(np.sqrt(1e-4 + 0.002 ** 2))


def test_replace_fusion_takes_the_belief():
    trk = PhysicsAwareTracker(TrackerConfig(pseudo_fusion="replace", velocity_std=0.5))
    for k in range(10):
        trk.update(frame(k * DT, ball=([0.1 * k * DT, 0.0, 0.7], None)))
    t = 10 * DT
    trk.update(frame(t))
    cov = np.diag([1e-4, 4e-4, 9e-4])
    trk.feedback(belief(t, ball=([0.3, 0.1, 0.5], cov)))
    tr = trk.tracks["ball"]
    r = cov + trk.config.pseudo_std_floor ** 2 * np.eye(3)
    np.testing.assert_allclose(tr.position, [0.3, 0.1, 0.5], atol=1e-15)
    np.testing.assert_allclose(tr.position_cov, r, atol=1e-15)
    np.testing.assert_allclose(tr.kf.x[3:, 0], 0.0)
    trk.predict(t + 0.1)  # stays put, its covariance grows by velocity_std^2 dt^2 and more
    np.testing.assert_allclose(tr.position, [0.3, 0.1, 0.5], atol=1e-15)
    assert np.all(np.diag(tr.position_cov) > np.diag(r) + 0.5 ** 2 * 0.1 ** 2 - 1e-12)
    with pytest.raises(ValueError, match="pseudo_fusion"):
        TrackerConfig(pseudo_fusion="average")


def test_time_going_backwards_is_an_error():
    trk = PhysicsAwareTracker()
    trk.update(frame(1.0, cup=([0, 0, 0.7], None)))
    with pytest.raises(ValueError, match="backwards"):
        trk.update(frame(0.5))
    with pytest.raises(ValueError, match="backwards"):
        trk.predict(0.9)
    with pytest.raises(ValueError, match="does not match"):
        trk.feedback(belief(0.5))


def test_config_is_checked():
    with pytest.raises(ValueError, match="measurement_std"):
        TrackerConfig(measurement_std=0.0)
    with pytest.raises(ValueError, match="gate_probability"):
        TrackerConfig(gate_probability=1.0)
    assert TrackerConfig().gate == pytest.approx(11.3449, abs=1e-3)


def test_a_student_t_belief_is_taken_as_the_gaussian_of_its_90_percent_region():
    trk = PhysicsAwareTracker(TrackerConfig(pseudo_fusion="replace"), object_ids=("cup", "ball"))
    trk.update(frame(0.0))
    cov = np.diag([4e-4, 1e-4, 9e-4])
    t3 = ObjectBelief(np.array([0.5, 0.0, 0.9]), np.array([0, 0, 0, 1.0]), cov, 0.0, False, 1.0, 0.0,
                      mean_position_cov=cov, position_dof=3.0)
    gauss = dataclasses.replace(t3, position_dof=math.inf)
    trk.feedback(Belief(0.0, {"cup": t3, "ball": gauss}, [], [], 1.0))
    floor = trk.config.pseudo_std_floor ** 2 * np.eye(3)
    got = trk.tracks["cup"].position_cov - floor
    # the Gaussian's 90 % ellipsoid is the t's: same axes, the chi2 radius over this covariance
    # equals the t's radius over the belief's
    np.testing.assert_allclose(got * chi2.ppf(0.9, 3), cov * region_radius_sq(0.9, 3.0), rtol=1e-12)
    assert np.all(np.diag(got) < np.diag(cov))  # narrower than the moments: 0.86 of them
    np.testing.assert_allclose(trk.tracks["ball"].position_cov - floor, cov, rtol=1e-12)  # a Gaussian as it is
    with pytest.raises(ValueError, match="pseudo_region"):
        TrackerConfig(pseudo_region=1.0)


def test_pseudo_measurement_is_the_whole_beliefs_moments_not_its_main_hypothesis():
    """A belief with two hypotheses reports the heavier one's position; the tracker takes the
    mixture's mean and covariance (mean_position, mean_position_cov), the Gaussian a Kalman filter
    can hold."""
    trk = PhysicsAwareTracker(TrackerConfig(pseudo_fusion="replace"), object_ids=("cup",))
    trk.update(frame(0.0))
    mode_cov, mix_cov = 1e-4 * np.eye(3), np.diag([4e-2, 1e-4, 1e-2])
    ob = ObjectBelief(np.array([0.5, 0.0, 0.9]), np.array([0, 0, 0, 1.0]), mode_cov, 0.0, False, 1.0, 0.7,
                      mean_position=np.array([0.3, 0.0, 0.6]), mean_position_cov=mix_cov)
    trk.feedback(Belief(0.0, {"cup": ob}, [], [], 1.0))
    tr = trk.tracks["cup"]
    np.testing.assert_allclose(tr.position, [0.3, 0.0, 0.6])
    np.testing.assert_allclose(tr.position_cov, mix_cov + trk.config.pseudo_std_floor ** 2 * np.eye(3))
