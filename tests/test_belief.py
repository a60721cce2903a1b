import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from actions.modes import FREE, HELD
from estimator.belief import compute_belief, pose_stats, support_labels


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
