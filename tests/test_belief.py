import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from actions.modes import FREE, HELD
from estimator.belief import (
    chi2_quantile,
    compute_belief,
    headline_positions,
    pose_stats,
    region_radius_sq,
    support_labels,
    with_added_variance,
)


def test_pose_stats_match_direct_formulas():
    rng = np.random.default_rng(3)
    k = 200
    pos = rng.normal([1, 2, 3], [0.1, 0.2, 0.3], size=(k, 3))
    rot = Rotation.from_rotvec(rng.normal(0, 0.1, (k, 3)))
    poses = np.concatenate([pos, rot.as_quat()], axis=1)
    w = rng.random(k)
    w /= w.sum()
    means, covs, quats, angs = pose_stats(poses[:, None], w)
    mean, cov, q, ang = means[0], covs[0], quats[0], angs[0]
    assert np.allclose(mean, w @ pos)
    assert np.allclose(cov, np.cov(pos.T, aweights=w, bias=True))
    assert Rotation.from_quat(q).magnitude() < 0.05 and 0.05 < ang < 0.3
    assert abs(abs(q @ rot.mean(weights=w).as_quat()) - 1) < 1e-9  # scipy's chordal mean
    one = pose_stats(poses[:1, None], np.ones(1))
    assert np.array_equal(one[0][0], pos[0]) and np.all(one[1] == 0) and one[3][0] == 0.0


def test_hypotheses_group_particles_by_support():
    # 4 particles, objects: 0 table (static), 1 box, 2 ball; floor is support index 3
    m = 3
    modes = np.array([[FREE, FREE, FREE], [FREE, FREE, FREE], [FREE, FREE, HELD], [FREE, FREE, FREE]])
    on_top = np.zeros((4, m, m + 1), bool)
    is_in = np.zeros((4, m, m), bool)
    on_top[:, 1, 0] = True          # box on table
    is_in[0, 2, 1] = True           # ball in box
    on_top[1, 2, 3] = True          # ball on floor
    on_top[3, 2, 3] = True
    labels = support_labels(modes, on_top, is_in)
    assert labels[:, 2].tolist() == [1 + 1, 1 + m + 3, 0, 1 + m + 3]
    poses = np.zeros((4, m, 7))
    poses[..., 6] = 1
    poses[:, 2, 2] = [0.7, 0.03, 1.0, 0.05]
    w = np.array([0.2, 0.3, 0.1, 0.4])
    b = compute_belief(1.0, ["table", "box", "ball"], np.ones(m, bool), np.zeros(m, bool), poses, w, modes,
                       on_top, is_in, [], 3.0, np.array([True, False, False]), cov_floor=1e-4)
    hyp = [(h.relation, h.support, round(h.p, 6)) for h in b.objects["ball"].hypotheses]
    assert hyp == [("isOnTop", "floor", 0.7), ("isIn", "box", 0.2), ("held", None, 0.1)]
    floor_h = b.objects["ball"].hypotheses[0]
    assert floor_h.position[2] == pytest.approx((0.3 * 0.03 + 0.4 * 0.05) / 0.7)
    assert b.objects["ball"].p_held == pytest.approx(0.1) and b.objects["ball"].p_plausible == 1.0
    assert b.relation_p("box", "isOnTop", "table") == 1.0 and b.relation_p("ball", "isIn", "box") == pytest.approx(0.2)
    assert b.objects["table"].hypotheses == () and np.all(b.objects["table"].position_cov == 0)
    assert b.objects["box"].position_cov[0, 0] == pytest.approx(1e-4)  # the floor
    j = b.to_json()
    assert j["objects"]["ball"]["hypotheses"][0] == {"p": 0.7, "relation": "isOnTop", "support": "floor",
                                                      "position": [0.0, 0.0, pytest.approx(0.041429, abs=1e-6)]}


def _cup_held_or_fallen(rng, k=400, p_floor=0.7):
    """A bimodal particle set of a cup (object 1; object 0 is a static table): a fraction
    ``p_floor`` of the weight on the floor near (1.0, 0.3, 0.05), the rest held near (0.2, 0.0, 1.0)."""
    m = 2
    floor = rng.random(k) < 0.5
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    poses[floor, 1, :3] = rng.normal([1.0, 0.3, 0.05], 0.01, (floor.sum(), 3))
    poses[~floor, 1, :3] = rng.normal([0.2, 0.0, 1.0], 0.02, ((~floor).sum(), 3))
    w = np.where(floor, p_floor / floor.sum(), (1 - p_floor) / (~floor).sum())
    modes = np.full((k, m), FREE)
    modes[~floor, 1] = HELD
    on_top = np.zeros((k, m, m + 1), bool)
    on_top[floor, 1, m] = True  # on the floor
    return poses, w, modes, on_top, np.zeros((k, m, m), bool), floor


@pytest.mark.parametrize("p_floor", [0.7, 0.3])
def test_a_bimodal_belief_reports_the_heavier_mode_not_the_mean(p_floor):
    rng = np.random.default_rng(12)
    poses, w, modes, on_top, is_in, floor = _cup_held_or_fallen(rng, p_floor=p_floor)
    b = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                       is_in, [], 100.0, np.array([True, False]), cov_floor=1e-6)
    cup = b.objects["cup"]
    heavy = floor if p_floor > 0.5 else ~floor
    assert cup.hypotheses[0].p == pytest.approx(max(p_floor, 1 - p_floor))
    # the headline is the heavier mode's weighted mean and covariance (+ the floor), where particles are
    expected = w[heavy] @ poses[heavy, 1, :3] / w[heavy].sum()
    assert np.allclose(cup.position, expected) and np.allclose(cup.position, cup.hypotheses[0].position)
    dev = poses[heavy, 1, :3] - expected
    assert np.allclose(cup.position_cov, (dev.T * w[heavy] / w[heavy].sum()) @ dev + 1e-6 * np.eye(3))
    assert np.sqrt(np.trace(cup.position_cov)) < 0.05  # one mode's spread: centimetres, not the gap
    # the overall mean lies between the modes, with the gap in its covariance, kept apart
    assert np.allclose(cup.mean_position, w @ poses[:, 1, :3])
    assert np.linalg.norm(cup.mean_position - cup.position) > 0.2
    assert np.sqrt(np.trace(cup.mean_position_cov)) > 0.3
    j = b.to_json()["objects"]["cup"]
    assert j["position"] == pytest.approx(cup.position.tolist(), abs=1e-6)
    assert j["mean_position"] == pytest.approx(cup.mean_position.tolist(), abs=1e-6)
    assert np.allclose(j["mean_position_cov"], cup.mean_position_cov, atol=1e-8)


def test_a_one_mode_belief_is_its_mean():
    rng = np.random.default_rng(5)
    poses, w, modes, on_top, is_in, floor = _cup_held_or_fallen(rng)
    modes[:] = FREE
    on_top[:, 1, 2] = True  # every particle says "on the floor"
    b = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                       is_in, [], 100.0, np.array([True, False]), cov_floor=1e-6)
    cup = b.objects["cup"]
    means, covs, _, _ = pose_stats(poses, w)
    assert len(cup.hypotheses) == 1
    assert np.array_equal(cup.position, means[1]) and np.array_equal(cup.mean_position, means[1])
    assert np.array_equal(cup.position_cov, covs[1] + 1e-6 * np.eye(3))
    assert np.array_equal(cup.mean_position_cov, cup.position_cov)
    one = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses[:1], np.ones(1),
                         modes[:1], on_top[:1], is_in[:1], [], 1.0, np.array([True, False]))
    assert np.array_equal(one.objects["cup"].position, poses[0, 1, :3])
    assert np.all(one.objects["cup"].position_cov == 0) and np.all(one.objects["cup"].mean_position_cov == 0)


def test_chi2_quantile_is_scipy_stats_value_for_value():
    """chi2_quantile (from scipy.special, so that the estimator does not import scipy.stats) gives
    scipy.stats.chi2.ppf's values exactly, and region_radius_sq of a t gives the F quantile's."""
    from scipy.stats import f as f_dist

    levels = np.array([1e-3, 0.025, 0.5, 0.9, 0.95, 0.975, 1 - 1e-3])
    for dof in (1, 2, 3, 6, 60, 3000):
        assert np.array_equal(chi2_quantile(levels, dof), chi2.ppf(levels, dof))
    assert isinstance(chi2_quantile(0.9, 3), float)
    for nu in (2.5, 3.0, 7.0, 40.0):
        assert np.array_equal(region_radius_sq(levels, nu), 3 * (nu - 2) / nu * f_dist.ppf(levels, 3, nu))


def test_region_radius_is_chi2_for_a_gaussian_and_holds_its_level_for_a_student_t():
    assert region_radius_sq(0.9, np.inf) == pytest.approx(chi2.ppf(0.9, 3))
    assert np.allclose(region_radius_sq([0.5, 0.9], np.inf), chi2.ppf([0.5, 0.9], 3))
    # a t of covariance C: a Gaussian of covariance C (nu - 2) / nu over sqrt(chi2(nu) / nu)
    rng = np.random.default_rng(11)
    n, nu = 40000, 3.0
    cov = np.array([[4e-4, 1e-4, 0.0], [1e-4, 1e-4, 0.0], [0.0, 0.0, 1e-5]])
    z = rng.multivariate_normal(np.zeros(3), cov * (nu - 2) / nu, size=n)
    x = z / np.sqrt(rng.chisquare(nu, size=n) / nu)[:, None]
    m2 = np.einsum("ni,ij,nj->n", x, np.linalg.inv(cov), x)
    for level in (0.5, 0.9, 0.99):
        band = 4 * np.sqrt(level * (1 - level) / n)
        assert np.mean(m2 <= region_radius_sq(level, nu)) == pytest.approx(level, abs=band)
    # of the same covariance, its 50 % and 90 % regions are narrower than the Gaussian's, its 99 % wider
    assert region_radius_sq(0.5, nu) < chi2.ppf(0.5, 3) and region_radius_sq(0.9, nu) < chi2.ppf(0.9, 3)
    assert region_radius_sq(0.99, nu) > chi2.ppf(0.99, 3)
    for bad in ((0.5, 2.0), (1.0, 3.0), (0.0, np.inf)):
        with pytest.raises(ValueError):
            region_radius_sq(*bad)


def test_beliefs_report_the_degrees_of_freedom_and_take_added_variance():
    rng = np.random.default_rng(5)
    poses, w, modes, on_top, is_in, floor = _cup_held_or_fallen(rng)
    b = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                       is_in, [], 100.0, np.array([True, False]), cov_floor=1e-6, dof=3.0)
    cup, table = b.objects["cup"], b.objects["table"]
    assert cup.position_dof == 3.0 and np.isinf(table.position_dof)  # static objects: no spread at all
    assert cup.to_json()["position_dof"] == 3.0 and table.to_json()["position_dof"] is None
    assert cup.region(0.9) == pytest.approx(region_radius_sq(0.9, 3.0))
    gauss = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                           is_in, [], 100.0, np.array([True, False]), cov_floor=1e-6)
    assert np.array_equal(gauss.objects["cup"].position_cov, cup.position_cov)  # the dof leaves the covariance
    assert gauss.objects["cup"].to_json()["position_dof"] is None
    assert np.array_equal(headline_positions(b), np.stack([table.position, cup.position]))
    more = with_added_variance(b, np.array([0.0, 4e-4]))
    assert np.allclose(more.objects["cup"].position_cov, cup.position_cov + 4e-4 * np.eye(3))
    assert np.allclose(more.objects["cup"].mean_position_cov, cup.mean_position_cov + 4e-4 * np.eye(3))
    assert np.array_equal(more.objects["table"].position_cov, table.position_cov)
    assert np.array_equal(more.objects["cup"].position, cup.position)
    for bad in (np.array([0.0]), np.array([0.0, -1.0]), np.array([0.0, np.nan])):
        with pytest.raises(ValueError):
            with_added_variance(b, bad)


def test_each_dynamic_object_reports_the_weighted_posterior_of_its_parameters():
    """``parameters``: weighted mean and standard deviation of friction, rolling friction, restitution
    and mass over the particles, for dynamic objects only (a static table has none), in the JSON
    line as {"mean", "std"}; without ``params`` nothing is reported."""
    rng = np.random.default_rng(7)
    poses, w, modes, on_top, is_in, _ = _cup_held_or_fallen(rng)
    K = len(w)
    params = np.zeros((K, 2, 5))
    params[:, 1, 1] = rng.uniform(0.001, 0.004, K)  # the cup's rolling friction
    params[:, 1, 4] = 0.2
    b = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                       is_in, [], 100.0, np.array([True, False]), params=params)
    rf = b.objects["cup"].parameters["rolling_friction"]
    mu = np.sum(w * params[:, 1, 1])
    assert rf[0] == pytest.approx(mu) and rf[1] == pytest.approx(np.sqrt(np.sum(w * (params[:, 1, 1] - mu) ** 2)))
    assert b.objects["cup"].parameters["mass"] == pytest.approx((0.2, 0.0), abs=1e-12)
    assert b.objects["table"].parameters is None
    line = b.to_json()["objects"]["cup"]["parameters"]["rolling_friction"]
    assert set(line) == {"mean", "std"} and line["mean"] == pytest.approx(mu, abs=1e-6)
    none = compute_belief(2.0, ["table", "cup"], np.ones(2, bool), np.zeros(2, bool), poses, w, modes, on_top,
                          is_in, [], 100.0, np.array([True, False]))
    assert none.objects["cup"].parameters is None and "parameters" not in none.to_json()["objects"]["cup"]
