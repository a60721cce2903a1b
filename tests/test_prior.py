"""The prior at rest (estimator/model/prior.py): objects start where physics leaves them, when that
is within the prior's uncertainty of the scene's pose."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.filter import SceneEstimator
from estimator.model import SceneModel, initial_poses
from estimator.model.prior import rest_prior
from estimator.observations import Frame
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
    poses, rested, _ = rest_prior(sc, given, known, PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, True]  # the table is static
    assert abs(poses[1, 2] - (TABLE_TOP + HALF)) < 2e-3 and poses[1, 2] < given[1, 2] - 0.003  # on the table, not 4 mm above
    assert quat_angle(poses[1, 3:], np.array([0, 0, 0, 1.0])) < np.radians(0.5)  # flat, not tilted
    assert np.linalg.norm(poses[1, :2] - given[1, :2]) < 0.01
    np.testing.assert_array_equal(poses[0], given[0])


def test_an_object_physics_would_move_beyond_the_reach_keeps_its_pose_and_does_not_move_the_others():
    sc = _scene(ball_height=0.3)
    given, known = initial_poses(sc)
    poses, rested, _ = rest_prior(sc, given, known, PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, True, False]
    np.testing.assert_array_equal(poses[2], given[2])  # the ball stays where the scene has it
    alone = rest_prior(_scene(), *initial_poses(_scene()), PhysicsSettings(), reach=0.03, turn=0.6)[0]
    np.testing.assert_allclose(poses[1], alone[1], atol=1e-9)  # the crate rests as if the ball were not there
    # a reach under the crate's own settling: it keeps its pose too
    poses, rested, _ = rest_prior(sc, given, known, PhysicsSettings(), reach=0.001, turn=0.6)
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


def test_the_prior_says_which_objects_rest_flat_on_static_bodies_alone():
    """The crate alone on the table rests flat on a static body; with a ball resting on it, neither
    does (each touches a dynamic object); on a static ramp tilted 10 degrees the crate touches only
    the ramp, but not flat (a particle with less friction would slide)."""
    sc = _scene()
    assert rest_prior(sc, *initial_poses(sc), PhysicsSettings(), reach=0.03, turn=0.6)[2].tolist() == [False, True]
    stacked = table_scene({"id": "crate", "box": {"size": [2 * HALF] * 3}, "mass": 0.3,
                           "pose": {"position": [0.1, 0.0, TABLE_TOP + HALF]}},
                          {"id": "ball", "sphere": {"radius": 0.02}, "mass": 0.05,
                           "pose": {"position": [0.1, 0.0, TABLE_TOP + 2 * HALF + 0.02]}, "rolling_friction": 0.01})
    _, rested, flat = rest_prior(stacked, *initial_poses(stacked), PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, True, True] and not flat.any()
    tilt = np.radians(10.0)
    ramp_q = quat_from_rotvec(np.array([tilt, 0.0, 0.0])).tolist()
    lift = 0.01 + HALF  # from the ramp's middle plane to the crate's centre, along the ramp's normal
    ramp = table_scene({"id": "ramp", "static": True, "box": {"size": [0.3, 0.3, 0.02]},
                        "pose": {"position": [0.1, 0.0, TABLE_TOP + 0.1], "orientation": ramp_q}},
                       {"id": "crate", "box": {"size": [2 * HALF] * 3}, "mass": 0.3, "friction": 0.9,
                        "pose": {"position": [0.1, -np.sin(tilt) * lift, TABLE_TOP + 0.1 + np.cos(tilt) * lift],
                                 "orientation": ramp_q}})
    _, rested, flat = rest_prior(ramp, *initial_poses(ramp), PhysicsSettings(), reach=0.03, turn=0.6)
    assert rested.tolist() == [False, False, True] and not flat.any()


def test_objects_the_prior_rests_flat_are_placed_asleep_and_never_settled_again():
    """The crate, hidden from the start and given 4 mm above the table tilted 4 degrees: the prior
    rests it flat, and the particles' horizontal perturbation only slides it along the table. Its
    worlds load it asleep: through the first updates it stays where each particle drew it (to a
    float round trip), at zero velocity. Without the prior at rest it falls and settles in every world."""
    sc = _scene()
    frames = [Frame(0.1 * i, {}) for i in range(4)]
    for rest in (True, False):
        cfg = EstimatorConfig(particles=16, workers=0, noise=NoiseConfig(), rest_prior=rest)
        with SceneEstimator(sc, cfg, np.random.default_rng(0)) as est:
            drawn = est.state.poses[:, 1].copy()
            for f in frames:
                est.update(f)
            # (to the float round trip of loading a pose and reading it back)
            still = np.abs(est.state.poses[:, 1] - drawn).max() < 1e-9 and np.all(est.state.velocities[:, 1] == 0.0)
            assert still == rest
