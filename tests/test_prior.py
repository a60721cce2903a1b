"""The prior at rest (estimator/model/prior.py): objects start where physics leaves them, when that
is within the prior's uncertainty of the scene's pose."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model import SceneModel, initial_poses
from estimator.model.prior import rest_prior
from helpers import TABLE_TOP, table_scene
from physics.transforms import quat_angle, quat_from_rotvec
from physics.world import PhysicsSettings

HALF = 0.03  # half size of the crate (m)
TILT = np.radians(4.0)


def _scene(ball_height=None):
    q = quat_from_rotvec(np.array([TILT, 0.0, 0.0])).tolist()
    objects = [{"id": "crate", "box": {"size": [2 * HALF] * 3}, "mass": 0.3,
                "pose": {"position": [0.1, 0.0, TABLE_TOP + HALF + 0.004], "orientation": q}}]
    if ball_height is not None:  # a ball the scene gives high above the crate (held, say)
        objects.append({"id": "ball", "sphere": {"radius": 0.02}, "mass": 0.5,
                        "pose": {"position": [0.1, 0.0, TABLE_TOP + ball_height]}})
    return table_scene(*objects)


def test_an_object_given_a_little_off_its_rest_starts_at_rest_on_its_support():
    sc = _scene()
    given, known = initial_poses(sc)
    poses, rested = rest_prior(sc, given, known, PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, True]  # the table is static
    assert abs(poses[1, 2] - (TABLE_TOP + HALF)) < 2e-3 and poses[1, 2] < given[1, 2] - 0.003  # on the table, not 4 mm above
    assert quat_angle(poses[1, 3:], np.array([0, 0, 0, 1.0])) < np.radians(0.5)  # flat, not tilted
    assert np.linalg.norm(poses[1, :2] - given[1, :2]) < 0.01
    np.testing.assert_array_equal(poses[0], given[0])


def test_an_object_physics_would_move_beyond_the_reach_keeps_its_pose_and_does_not_move_the_others():
    sc = _scene(ball_height=0.3)
    given, known = initial_poses(sc)
    poses, rested = rest_prior(sc, given, known, PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, True, False]
    np.testing.assert_array_equal(poses[2], given[2])  # the ball stays where the scene has it
    alone = rest_prior(_scene(), *initial_poses(_scene()), PhysicsSettings(), reach=0.03, turn=0.6)[0]
    np.testing.assert_allclose(poses[1], alone[1], atol=1e-9)  # the crate rests as if the ball were not there
    # a reach under the crate's own settling: it keeps its pose too
    poses, rested = rest_prior(sc, given, known, PhysicsSettings(), reach=0.001, turn=0.6)
    assert not rested.any()
    np.testing.assert_array_equal(poses, given)


def test_the_particles_start_from_the_prior_at_rest_and_paper_mode_from_the_scene():
    sc = _scene()
    given = initial_poses(sc)[0]
    base = np.tile([0.5, 0.0, 0.0, 0.1, 0.3], (len(sc.objects), 1))
    cfg = EstimatorConfig(particles=200, noise=NoiseConfig())
    model = SceneModel(sc, cfg, base)
    st = model.initial_state(np.random.default_rng(0))
    assert np.all(np.abs(st.poses[:, 1, 2] - (TABLE_TOP + HALF)) < 2e-3) and np.all(st.poses[:, 1, 2] < given[1, 2] - 0.003)
    assert np.all(quat_angle(st.poses[:, 1, 3:], np.array([0, 0, 0, 1.0])) < np.radians(0.5))
    # horizontally, the prior's position noise around the rest pose: mean within 3 standard errors
    xy = st.poses[:, 1, :2] - model.prior[1, :2]
    assert np.all(np.abs(xy.mean(axis=0)) < 3 * cfg.noise.position_std / np.sqrt(200))
    paper = SceneModel(sc, EstimatorConfig.paper(), base)
    np.testing.assert_array_equal(paper.initial_state(np.random.default_rng(0)).poses[0], given)
    off = SceneModel(sc, EstimatorConfig(particles=4, noise=NoiseConfig(), rest_prior=False), base)
    np.testing.assert_array_equal(off.prior, given)
