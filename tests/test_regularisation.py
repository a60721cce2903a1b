"""After resampling: estimator.model.regularisation."""
import numpy as np
import pytest

from actions.modes import HELD
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.noise import Kernel
from estimator.model.params import param_bounds
from estimator.model.regularisation import (
    bounding_radii,
    carried_at_rest,
    placed_at_rest,
    regularisation_kernels,
    regularise,
    slid_at_rest,
)
from model_helpers import BALL, CRATE, CUP, MYSTERY, TABLE, make


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
    cov = kernels[BALL].chol @ kernels[BALL].chol.T
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


def test_a_growth_regularises_only_the_new_copies_towards_the_weighted_mean():
    """``rows``: 2000 particles and 2000 copies of them drawn by weight (a growth by splitting, the
    weights shared among each particle and its copies); only the copies' hidden ball and parameters
    move. They keep the weighted mean of the ball within four standard errors (sd / sqrt(2000):
    0.18 cm), where a shrinkage towards the plain mean of the rows (0.5 cm off it: two clusters 4 cm
    apart, weighed 3 to 1) would move them by (1 - sqrt(1 - 0.9^2)) 0.5 cm = 0.28 cm; and its spread."""
    nz = NoiseConfig(regularisation=0.9, max_jitter_std=0.05, param_jitter=0.1)
    model = make(EstimatorConfig(particles=4000, noise=nz))
    rng = np.random.default_rng(21)
    st = model.initial_state(rng)
    st.poses[:2000, BALL, 0] += rng.normal(0.0, 0.01, 2000) + np.where(np.arange(2000) < 1000, 0.0, 0.04)
    w = np.where(np.arange(2000) < 1000, 3.0, 1.0)
    w /= w.sum()
    copies = rng.choice(2000, 2000, p=w)
    st.poses[2000:], st.params[2000:] = st.poses[copies], st.params[copies]
    counts = 1 + np.bincount(copies, minlength=2000)
    weights = np.concatenate([w / counts, w[copies] / counts[copies]])
    hidden = np.zeros(5, bool)
    hidden[BALL] = True
    kernels = regularisation_kernels(model, st.poses[:2000], w, hidden)
    before, params = st.poses.copy(), st.params.copy()
    regularise(model, st, kernels, np.random.default_rng(22), rows=np.arange(4000) >= 2000, weights=weights)
    assert np.array_equal(st.poses[:2000], before[:2000]) and np.array_equal(st.params[:2000], params[:2000])
    assert np.all(st.poses[2000:, BALL, 0] != before[2000:, BALL, 0]) and np.any(st.params[2000:] != params[2000:])
    x0 = before[:2000, BALL, 0]
    mean, sd = w @ x0, np.sqrt(w @ (x0 - w @ x0) ** 2)
    assert abs(st.poses[2000:, BALL, 0].mean() - mean) < 4 * sd / np.sqrt(2000)
    assert abs(st.poses[2000:, BALL, 0].std() / sd - 1.0) < 4 / np.sqrt(2 * 2000)


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
    even = regularisation_kernels(model, st.poses, np.full(400, 1 / 400), hidden)[BALL].chol
    assert np.allclose(even @ even.T, 0.25 * cov, rtol=1e-6, atol=1e-12)
    w = np.full(400, 1e-12)
    w[0] = 1.0
    w /= w.sum()
    one = regularisation_kernels(model, st.poses, w, hidden)[BALL].chol
    share = 1.0 / (400 * np.sum(w ** 2))
    mixed = share * w + (1.0 - share) / 400
    assert np.allclose(one @ one.T, 0.25 * np.cov(st.poses[:, BALL, :3].T, aweights=mixed, bias=True),
                       rtol=1e-6, atol=1e-12)
    assert np.trace(one @ one.T) > 0.9 * np.trace(even @ even.T)


def test_the_jitter_keeps_a_hidden_clouds_mean_and_spread():
    """Liu-West: each copy is drawn towards the mean by sqrt(1 - h^2) before its jitter of h^2 times
    the covariance, so one regularisation keeps the cloud's mean (within 3 standard errors of the
    jitter's mean) and its covariance's trace (within 3 standard deviations of the ratio of the
    sample traces: per axis sqrt((2 h^4 + 4 (1 - h^2) h^2) / n) relative, the axes weighted by their
    share of the trace), where the plain jitter would multiply it by 1 + h^2 = 1.25."""
    n, h = 4000, 0.5
    nz = NoiseConfig(regularisation=h, max_jitter_std=1.0, param_jitter=0.0)
    model = make(EstimatorConfig(particles=n, noise=nz))
    rng = np.random.default_rng(11)
    st = model.initial_state(rng)
    st.poses[:, BALL, :3] = [0.0, 0.0, 1.2] + rng.normal(0.0, [0.01, 0.02, 0.005], (n, 3))  # in the air
    st.poses[:, BALL, 3:] = [0.0, 0.0, 0.0, 1.0]
    hidden = np.zeros(5, bool)
    hidden[BALL] = True
    kernels = regularisation_kernels(model, st.poses, np.full(n, 1.0 / n), hidden)
    assert kernels[BALL].shrink == pytest.approx(np.sqrt(1.0 - h ** 2))
    before = st.poses[:, BALL, :3].copy()
    regularise(model, st, kernels, np.random.default_rng(12))
    after = st.poses[:, BALL, :3]
    assert np.all(after != before)
    se = h * before.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(after.mean(axis=0) - before.mean(axis=0)) < 3.0 * se)
    var = before.var(axis=0)
    share = var / var.sum()  # each axis's part of the trace
    ratio = np.trace(np.cov(after.T)) / np.trace(np.cov(before.T))
    band = 3.0 * np.sqrt((2 * h ** 4 + 4 * (1 - h ** 2) * h ** 2) / n * np.sum(share ** 2))
    assert abs(ratio - 1.0) < band < 0.25
    model.close()


def test_an_object_kept_by_its_particle_is_carried_at_rest_with_its_level_support_and_nothing_in_its_way():
    """The ball rests in the crate in every particle, which keeps its own ball (nothing weighed it)
    and takes its ancestor's crate, shifted and turned about the vertical: the ball comes along, at
    rest as a world would have left it. Not when the crate tilts, when either was moving, or when
    the ancestor has the cup where the ball lands."""
    model = make(EstimatorConfig(particles=6))
    st = model.initial_state(np.random.default_rng(0))
    st.poses[:, CUP, :3] = [0.3, 0.3, 0.14]
    st.velocities[:] = 0.0
    st.is_in[:] = False
    st.is_in[:, BALL, CRATE] = True
    st.poses[:, CRATE, 0] += 0.02 * np.arange(6)  # each particle's crate a little further along x
    yaw = np.array([0.0, 0.0, np.sin(0.1), np.cos(0.1)])
    st.poses[1, CRATE, 3:] = yaw  # particle 1's crate turned 0.2 rad about the vertical
    st.poses[5, CRATE, 3:] = [np.sin(0.05), 0.0, 0.0, np.cos(0.05)]  # particle 5's tilted 0.1 rad
    st.velocities[3, BALL, 0] = 0.1  # particle 3's ball rolling
    st.poses[4, CUP, :3] = st.poses[4, CRATE, :3]  # particle 4's cup in its crate, 8 cm from its ball
    own = np.zeros(5, bool)
    own[BALL] = True
    # particle 0 takes the turned crate, 2 the tilted one, 3 particle 0's; the others their own
    anc = np.array([1, 1, 5, 0, 4, 5])
    after = st.take(anc, own)
    radii = bounding_radii(np.array([[[-0.5, -0.5, 0], [0.5, 0.5, 0.1]], [[-0.15, -0.1, 0.1], [0.15, 0.1, 0.22]],
                                     [[0.05, -0.03, 0.11], [0.11, 0.03, 0.17]], [[0.27, 0.27, 0.1], [0.33, 0.33, 0.18]],
                                     [[np.nan] * 3, [np.nan] * 3]]), model.prior[:, :3])
    assert abs(radii[BALL] - np.sqrt(3) * 0.03) < 1e-9
    mask, poses = carried_at_rest(model, st, after, anc, own, radii)
    assert poses is after.poses
    # the ball moved with the turned crate: its pose relative to the crate is particle 0's
    rel_before = st.poses[0, BALL, :3] - st.poses[0, CRATE, :3]
    rel_after = after.poses[0, BALL, :3] - after.poses[0, CRATE, :3]
    assert np.linalg.norm(rel_after) == pytest.approx(np.linalg.norm(rel_before))
    assert mask[:, BALL].tolist() == [True, True, False, False, False, True]
    assert mask[:, [TABLE, CRATE, CUP, MYSTERY]].sum() == 0
    assert carried_at_rest(model, st, after, anc, np.zeros(5, bool), radii) is None


def test_a_hidden_object_slid_along_a_flat_static_top_at_rest_counts_as_at_rest_there():
    """The cup stands alone on the table (a static box) in six particles, each moved to another
    place. Only the one slid 6 mm along the top (its height 2 micrometres off, within the
    tolerance) slid at rest. Not the one moved half over the table's edge (the table no longer
    holds it up under two corners of its box), the one moving, the one moved within 2 cm of the
    crate, the one turned, the one raised 1 mm."""
    model = make(EstimatorConfig(particles=6))
    assert model.geometry is not None
    st = model.initial_state(np.random.default_rng(0))
    st.velocities[:] = 0.0
    st.on_top[:], st.is_in[:] = False, False
    st.on_top[:, CUP, TABLE] = True
    st.is_in[:, BALL, CRATE] = True
    before = st.poses[:, CUP].copy()
    st.poses[0, CUP, :3] += [0.005, -0.003, 2e-6]
    st.poses[1, CUP, :2] = [0.5, 0.3]
    st.poses[2, CUP, :2] += 0.004
    st.velocities[2, CUP, 0] = 0.01
    st.poses[3, CUP, :2] = [0.19, 0.0]
    st.poses[4, CUP, :2] += 0.004
    st.poses[4, CUP, 3:] = [np.sin(0.01), 0.0, 0.0, np.cos(0.01)]
    st.poses[5, CUP, :3] += [0.004, 0.0, 0.001]
    slid = slid_at_rest(model, st, CUP, np.arange(6), before, np.ones(6, bool))
    assert slid.tolist() == [True, False, False, False, False, False]
    # not when the worlds did not make it where it was (displaced without physics since)
    assert not slid_at_rest(model, st, CUP, np.arange(6), before, np.zeros(6, bool)).any()
    model.close()


def test_regularise_loads_the_copies_it_only_slid_at_rest_and_jolts_the_others():
    """Jittered along the table (a kernel with no vertical part but the regulariser's), the cup's
    copies slid at rest: their height is their own again bit for bit, they are not jolted (not
    pushed out of penetration, which would wake them) and the resampling hands them to the pool as
    at rest (:meth:`SceneModel.carried_at_rest`). The ball's copies, in the crate, are jolted."""
    nz = NoiseConfig(regularisation=0.5, max_jitter_std=0.01, param_jitter=0.0)
    model = make(EstimatorConfig(particles=50, noise=nz))
    st = model.initial_state(np.random.default_rng(1))
    st.velocities[:] = 0.0
    st.on_top[:], st.is_in[:] = False, False
    st.on_top[:, CUP, TABLE] = True
    st.is_in[:, BALL, CRATE] = True
    before = st.take(np.arange(50))
    kernel = Kernel(np.diag([0.004, 0.004, 1e-6]), 0.9)  # drawn towards the mean along the table too
    slid = regularise(model, st, {CUP: kernel, BALL: kernel}, np.random.default_rng(2))
    assert slid[:, CUP].all() and not slid[:, [TABLE, CRATE, BALL, MYSTERY]].any()
    assert np.array_equal(st.poses[:, CUP, 2], before.poses[:, CUP, 2])
    assert np.all(st.poses[:, CUP, :2] != before.poses[:, CUP, :2])
    assert not st.jolted[:, CUP].any() and st.jolted[:, BALL].all()
    at_rest, poses = model.carried_at_rest(before, st, np.arange(50), np.zeros(5, bool),
                                           np.tile([[-0.5, -0.5, 0.0], [0.5, 0.5, 0.2]], (5, 1, 1)), slid)
    assert np.array_equal(at_rest, slid) and poses is st.poses
    model.close()


def test_the_first_placement_leaves_at_rest_what_it_only_slid_along_a_flat_static_top():
    """The cup rests flat on the table (a static box) at the prior's pose; eight particles place it.
    At rest are the one slid 6 mm along the top (its height 2 micrometres off: set back to the
    prior's, bit for bit) and the one left where the prior has it. Not the one half over the
    table's edge, the one moving, the one within 2 cm of the crate, the one turned, the one held,
    the one raised 1 mm. The crate, with the ball in it, is never at rest so (the ball is within its
    box)."""
    model = make(EstimatorConfig(particles=8))
    prior = model.prior.copy()
    poses = np.repeat(prior[None], 8, axis=0)
    vel, modes = np.zeros((8, 5, 6)), np.zeros((8, 5), np.int8)
    poses[0, CUP, :3] += [0.005, -0.003, 2e-6]
    poses[2, CUP, :2] = [0.5, 0.3]
    vel[3, CUP, 0] = 0.01
    poses[4, CUP, :2] = [0.19, 0.0]
    poses[5, CUP, 3:] = [np.sin(0.01), 0.0, 0.0, np.cos(0.01)]
    modes[6, CUP] = HELD
    poses[7, CUP, 2] += 0.001
    flat = np.zeros(5, bool)
    flat[[CRATE, CUP]] = True
    placed = placed_at_rest(model, poses, vel, modes, flat, prior)
    assert placed[:, CUP].tolist() == [True, True, False, False, False, False, False, False]
    assert not placed[:, [TABLE, CRATE, BALL, MYSTERY]].any()
    assert poses[0, CUP, 2] == prior[CUP, 2] and poses[7, CUP, 2] == prior[CUP, 2] + 0.001
    model.close()



def test_a_change_of_k_leaves_an_object_that_every_particle_kept_where_it_averaged():
    """The cup, hidden and weighed by nothing, is kept by every particle (its own value, not its
    ancestor's). Shrinking 64 particles to 40 drops the values of the last 24, growing them to 100
    repeats ancestors' values: either moved the cloud's average by the chance of which. After the
    change the free copies are moved back, every one by the same horizontal shift, to where they
    averaged before; the cloud keeps its shape; with K unchanged, nothing moves."""
    model = make(EstimatorConfig(particles=64, noise=NoiseConfig(position_std=0.01, regularisation=0.0,
                                                                  param_jitter=0.0)))
    st = model.initial_state(np.random.default_rng(4))
    st.poses[:, CUP, :2] += np.random.default_rng(5).normal(0.0, 0.01, (64, 2))
    st.velocities[:] = 0.0
    own = np.zeros(5, bool)
    own[CUP] = True
    centre = st.poses[:, CUP, :3].mean(axis=0)
    for n in (40, 100, 64):
        anc = np.sort(np.random.default_rng(n).choice(64, n))
        after = st.take(anc, own)
        kept = after.poses[:, CUP].copy()
        model.after_resampling(after, {}, np.random.default_rng(6), st, own)
        if n == 64:
            assert np.array_equal(after.poses[:, CUP], kept)
            continue
        assert abs(kept[:, :2].mean(axis=0) - centre[:2]).max() > 1e-4  # the change moved it
        np.testing.assert_allclose(after.poses[:, CUP, :2].mean(axis=0), centre[:2], atol=1e-12)
        shift = after.poses[:, CUP, :2] - kept[:, :2]
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)
        model.K = 64
    model.close()
