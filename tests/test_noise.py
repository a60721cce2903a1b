"""The scene model's noise (estimator.model.noise): process noise and regularisation kernels, alone."""
import numpy as np

from estimator.config import NoiseConfig
from estimator.model.noise import centred_normal, process_noise, regularisation_kernels


def _poses(K, M):
    p = np.zeros((K, M, 7))
    p[..., 6] = 1.0
    return p


def test_process_noise_has_the_stated_spread_moves_supported_objects_along_their_support_only():
    K, dt = 20000, 0.1
    nz = NoiseConfig(process_position_std=0.003, motion_noise=0.3, max_jitter_std=0.01)
    poses = _poses(K, 3)
    free = np.ones((K, 3), bool)
    free[:, 2] = False  # not free-unseen: untouched
    supported = np.zeros((K, 3), bool)
    supported[:, 0] = True
    moved = np.zeros((K, 3))
    moved[:, 0] = 0.02  # rolled 2 cm in the last update
    jolted = process_noise(poses, free, supported, moved, dt, nz, np.random.default_rng(0))
    s_rolling = np.sqrt(0.003 ** 2 * dt + (0.3 * 0.02) ** 2)  # 6.1 mm
    s_free = 0.003 * np.sqrt(dt)  # flight is not noised beyond the walk: 0.95 mm
    for m, s, axes in ((0, s_rolling, (0, 1)), (1, s_free, (0, 1, 2))):
        sd = poses[:, m, list(axes)].std(axis=0)
        assert np.all(np.abs(sd - s) < 3 * s / np.sqrt(2 * K)), (m, sd, s)
    assert np.all(poses[:, 0, 2] == 0.0)  # on its support: not into it
    assert np.all(poses[:, 2] == _poses(K, 3)[:, 2])
    assert jolted[:, 0].all() and not jolted[:, 1:].any()  # 2 mm std or more
    # on a support the orientation turns about the vertical only
    assert np.allclose(poses[:, 0, 3:5], 0.0) and not np.allclose(poses[:, 1, 3:5], 0.0)


def test_regularisation_kernel_is_the_scaled_covariance_capped_at_max_std():
    rng = np.random.default_rng(1)
    K = 5000
    poses = _poses(K, 2)
    poses[:, 0, :3] = rng.normal(0.0, [0.01, 0.02, 0.005], (K, 3))
    poses[:, 1, :3] = rng.normal(0.0, 0.2, (K, 3))
    w = np.full(K, 1.0 / K)
    k = regularisation_kernels(poses, w, np.array([True, True]), 0.5, 0.01)
    cov0 = np.cov(poses[:, 0, :3].T, bias=True)
    assert np.allclose(k[0].chol @ k[0].chol.T, 0.25 * cov0, rtol=1e-6, atol=1e-12)  # within the cap: h^2 cov
    big = k[1].chol @ k[1].chol.T
    assert np.sqrt(np.max(np.linalg.eigvalsh(big))) <= 0.01 + 1e-9  # capped
    assert regularisation_kernels(poses, w, np.array([True, True]), 0.0, 0.01) == {}
    assert list(regularisation_kernels(poses, w, np.array([False, True]), 0.5, 0.01)) == [1]


def test_centred_normal_has_a_zero_mean_over_the_particles_and_keeps_the_stated_spread():
    """Each draw minus the particles' mean, scaled by sqrt(K / (K - 1)): the mean over the K
    particles is zero to rounding, and over many independent clouds each entry's variance is
    std^2 (within 3 standard errors of a sample variance, sqrt(2 / dof) std^2)."""
    rng = np.random.default_rng(11)
    K, std, n = 8, 0.01, 4000
    clouds = np.stack([centred_normal(rng, std, (K, 3, 2)) for _ in range(n)])  # (n, K, 3, 2)
    assert np.abs(clouds.mean(axis=1)).max() < 1e-15
    var = np.mean(clouds ** 2)  # (the mean is known: zero)
    dof = n * (K - 1) * 6  # (the K entries of a cloud share one mean)
    assert abs(var - std ** 2) < 3 * np.sqrt(2.0 / dof) * std ** 2  # without the scaling: 7/8 std^2
    one = centred_normal(np.random.default_rng(3), std, (1, 2))  # one particle: a plain draw
    np.testing.assert_array_equal(one, np.random.default_rng(3).normal(0.0, std, (1, 2)))
