"""After resampling: estimator.model.regularisation."""
import numpy as np

from actions.modes import HELD
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.params import param_bounds
from estimator.model.regularisation import regularisation_kernels, regularise
from model_helpers import BALL, CRATE, CUP, TABLE, make


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
