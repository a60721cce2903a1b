"""Perception fault model: configuration checks and noise statistics against the configuration.

Statistical checks use tolerance bands from the sample size: a sample mean within 4 sigma / sqrt(n)
of its expectation, a sample standard deviation within 4 / sqrt(2 n) relative error, a frequency
within 4 sqrt(p (1 - p) / n) of p (all seeded, so they are deterministic; the bands only make sure
the checks are not tuned to one draw).
"""
import dataclasses
import math

import numpy as np
import pytest

from experiments.scenarios import load_scenario
from experiments.simulation.perception import PerceptionConfig, PerceptionModel
from experiments.simulation.simulator import simulate
from physics.transforms import quat_angle, quat_conjugate, quat_multiply, quat_to_rotvec

M = 5
IDS = tuple(f"o{i}" for i in range(M))


def _true_poses(rng):
    poses = np.zeros((M, 7))
    poses[:, :3] = rng.uniform(-0.5, 0.5, (M, 3))
    q = rng.normal(size=(M, 4))
    poses[:, 3:] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return poses


def _run(cfg, n, *, static=None, visible=None, seed=7):
    rng = np.random.default_rng(seed)
    truth = _true_poses(np.random.default_rng(99))
    static = np.zeros(M, bool) if static is None else static
    visible = np.ones(M, bool) if visible is None else visible
    model = PerceptionModel(cfg, IDS, static, rng)
    obs = [model.observe(truth, visible, np.array([0.1, 0.2, 0.9])) for _ in range(n)]
    return model, truth, obs


def test_config_defaults_and_validation():
    cfg = PerceptionConfig()
    assert cfg.rate_hz == 30.0 and cfg.visibility_threshold == 0.3 and cfg.latency_s == 0.0
    for bad in ({"position_std": -0.1}, {"dropout_prob": 1.5}, {"rate_hz": 0}, {"height_offset": (0.02, 0.01)},
                {"visibility_threshold": 0.0}, {"points_per_object": 2}, {"latency_s": float("nan")}):
        with pytest.raises(ValueError):
            PerceptionConfig(**bad)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.position_std = 1.0


def test_position_noise_mean_and_std_match_configuration():
    sigma, n = 0.005, 2000
    _, truth, obs = _run(PerceptionConfig(position_std=sigma), n)
    err = np.stack([o.poses[:, :3] for o in obs]) - truth[:, :3]  # (n, M, 3)
    flat = err.reshape(-1, 3)
    k = len(flat)
    assert np.all(np.abs(flat.mean(axis=0)) < 4 * sigma / math.sqrt(k))
    assert np.all(np.abs(flat.std(axis=0, ddof=1) / sigma - 1) < 4 / math.sqrt(2 * k))


def test_height_offset_is_constant_per_object_and_inside_range():
    sigma, n = 0.002, 1500
    model, truth, obs = _run(PerceptionConfig(position_std=sigma, height_offset=(0.01, 0.02)), n)
    assert np.all((model.height_offsets >= 0.01) & (model.height_offsets <= 0.02))
    assert np.ptp(model.height_offsets) > 0  # drawn per object
    dz = np.stack([o.poses[:, 2] for o in obs]) - truth[:, 2]  # (n, M)
    assert np.all(np.abs(dz.mean(axis=0) - model.height_offsets) < 4 * sigma / math.sqrt(n))
    dxy = np.stack([o.poses[:, :2] for o in obs]) - truth[:, :2]
    assert np.all(np.abs(dxy.mean(axis=0)) < 4 * sigma / math.sqrt(n))


def test_interpenetration_and_dropout_frequencies():
    p_pen, p_drop, depth, n = 0.1, 0.05, 0.015, 3000
    _, truth, obs = _run(PerceptionConfig(interpenetration_prob=p_pen, interpenetration_depth=depth,
                                          dropout_prob=p_drop), n)
    reported = np.stack([o.reported for o in obs])
    k = reported.size
    drop_rate = 1 - reported.mean()
    assert abs(drop_rate - p_drop) < 4 * math.sqrt(p_drop * (1 - p_drop) / k)
    dz = np.stack([o.poses[:, 2] for o in obs]) - truth[:, 2]
    dz = dz[reported]
    sunk = np.isclose(dz, -depth)
    assert np.all(sunk | np.isclose(dz, 0.0))  # no other noise configured
    assert abs(sunk.mean() - p_pen) < 4 * math.sqrt(p_pen * (1 - p_pen) / len(dz))


def test_orientation_noise_angle_statistics():
    sigma_deg, n = 2.0, 2000
    _, truth, obs = _run(PerceptionConfig(orientation_std_deg=sigma_deg), n)
    q = np.stack([o.poses[:, 3:] for o in obs]).reshape(-1, 4)
    q_true = np.tile(truth[:, 3:], (n, 1))
    rel = quat_multiply(quat_conjugate(q_true), q)  # noise in the object frame
    rv = quat_to_rotvec(rel)
    s = math.radians(sigma_deg)
    k = len(rv)
    assert np.all(np.abs(rv.mean(axis=0)) < 4 * s / math.sqrt(k))
    # |rotvec|^2 / sigma^2 is chi-square with 3 degrees of freedom: mean 3, variance 6
    chi = (rv ** 2).sum(axis=1) / s ** 2
    assert abs(chi.mean() - 3.0) < 4 * math.sqrt(6.0 / k)


def test_fixed_orientation_static_and_invisible_objects():
    static = np.array([True, False, False, False, False])
    visible = np.array([True, True, False, True, True])
    cfg = PerceptionConfig(orientation_std_deg=5.0, fixed_orientation=("o3",))
    _, truth, obs = _run(cfg, 50, static=static, visible=visible)
    for o in obs:
        assert list(o.reported) == [False, True, False, True, True]
        assert np.allclose(o.poses[3, 3:], [0, 0, 0, 1])
        assert quat_angle(o.poses[1, 3:], truth[1, 3:]) > 0
    cfg_all = PerceptionConfig(fixed_orientation=("*",), report_static=True)
    _, _, obs = _run(cfg_all, 5, static=static)
    assert all(o.reported[0] and np.allclose(o.poses[:, 3:], [0, 0, 0, 1]) for o in obs)


def test_same_seed_same_stream_and_visibility_does_not_shift_noise():
    cfg = PerceptionConfig(position_std=0.01, dropout_prob=0.1, hands_tracked=True, hand_std=0.02)
    _, _, a = _run(cfg, 30, seed=3)
    _, _, b = _run(cfg, 30, seed=3)
    _, _, c = _run(cfg, 30, seed=3, visible=np.array([False, True, True, True, True]))
    for x, y, z in zip(a, b, c):
        assert np.array_equal(x.poses, y.poses, equal_nan=True) and np.array_equal(x.hand, y.hand)
        assert np.array_equal(x.poses[1:], z.poses[1:], equal_nan=True)
    assert a[0].hand is not None and not np.allclose(a[0].hand, [0.1, 0.2, 0.9])


def test_simulated_observations_match_configured_noise():
    """End to end: a static scenario perceived with known noise; observations minus truth."""
    sc = load_scenario("static_floating")
    sigma, offset = 0.004, 0.015
    cfg = PerceptionConfig(position_std=sigma, height_offset=(offset, offset))
    result = simulate(dataclasses.replace(sc, perception=cfg), seed=5, duration=2.0)
    errs = []
    for obs, tru in zip(result.observations, result.truth):
        assert obs["t"] == tru["t"]
        for oid, o in obs["objects"].items():
            errs.append(np.subtract(o["position"], tru["objects"][oid]["position"]))
    err = np.array(errs)
    k = len(err)
    assert k > 250
    expected = np.array([0.0, 0.0, offset])
    # rounding to 1e-6 m is far below the band
    assert np.all(np.abs(err.mean(axis=0) - expected) < 4 * sigma / math.sqrt(k))
    assert np.all(np.abs(err.std(axis=0, ddof=1) / sigma - 1) < 4 / math.sqrt(2 * k))
