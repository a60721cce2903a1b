"""estimator.model.scene_model: the scene model's prior, its move and its contract, on hand-built particle arrays (no worlds)."""

import numpy as np

from actions.modes import FREE
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model import SceneModel, initial_poses
from estimator.model.perception_memory import PerceptionMemory
from estimator.observations import Detection, Frame
from model_helpers import BALL, CRATE, CUP, MYSTERY, TABLE, make, scene


def test_initial_state_parks_unknown_objects_and_draws_parameters_from_their_priors():
    nz = NoiseConfig(position_std=0.01)
    model = make(EstimatorConfig(particles=64, noise=nz))
    st = model.initial_state(np.random.default_rng(0))
    assert list(model.known) == [True, True, True, True, False]
    assert np.all(st.poses[:, MYSTERY, :3] == [50.0 + 3.0 * MYSTERY, 50.0, -50.0])
    assert np.all(st.poses[:, TABLE, :3] == [0, 0, 0.05])  # static: never perturbed
    spread = st.poses[:, BALL, :3] - [0.08, 0.0, 0.14]
    assert 0.006 < spread[:, :2].std() < 0.014 and np.all(spread[:, :2] != 0)
    assert np.all(spread[:, 2] == 0)  # horizontally only: not pushed into its support nor dropped on it
    assert np.abs(spread[:, :2].mean(axis=0)).max() < 1e-12  # centred: the cloud's mean is the prior's
    fr = st.params[:, 1:, 0]
    assert np.all((fr >= 0.3) & (fr <= 1.0)) and fr.std() > 0.1
    assert np.all(st.params[:, TABLE] == [0.5, 0.0, 0.0, 0.1, 0.2])
    mass = st.params[:, 1:, 4] / 0.2
    assert np.all((mass >= 0.8) & (mass <= 1.25))
    assert st.modes.dtype == np.int8 and np.all(st.modes == FREE) and np.all(st.log_weights == 0)


def test_move_teleports_a_first_sighting_and_makes_it_known():
    model = make(EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.01)))
    st = model.initial_state(np.random.default_rng(0))
    frame = Frame(0.5, {"mystery": Detection(np.array([0.1, -0.1, 0.2]))})
    detected = model.memory.record(frame)
    perceived = model.memory.perceived(0.5)
    mv = model.move(st, frame, detected, perceived, 0.0, np.random.default_rng(3))
    assert list(mv.teleported) == [False, False, False, False, True] and model.known[MYSTERY]
    assert np.all(np.abs(mv.poses[:, MYSTERY, :3] - [0.1, -0.1, 0.2]) < 0.05)
    assert np.all(mv.predicted[:, MYSTERY, :3] == [50.0 + 3.0 * MYSTERY, 50.0, -50.0])
    assert np.all(mv.depenetrate[:, MYSTERY]) and np.all(mv.check[:, MYSTERY])
    assert np.all(mv.target[:, MYSTERY, :3] == [0.1, -0.1, 0.2])  # checked against the perception itself


def test_a_first_sighting_where_the_scene_places_the_object_moves_it_horizontally_only():
    """The crate's first detection 6 mm above and 4 mm beside where the scene places it, tilted, is
    within the tracker's noise of that pose: each particle takes the detection's horizontal position
    (plus noise) but keeps its own height and orientation (its support's), so a noisy height does
    not put it into what it rests on or under. 10 cm away, or in paper mode, Algorithm 2 places it
    at the detection in full (height with noise, the detection's orientation)."""
    tilt = np.array([np.sin(0.1), 0.0, 0.0, np.cos(0.1)])  # 0.2 rad about x
    for dx, aware, level in ((0.004, True, True), (0.10, True, False), (0.004, False, False)):
        model = make(EstimatorConfig(particles=200, noise=NoiseConfig(position_std=0.01), noise_aware_jumps=aware))
        st = model.initial_state(np.random.default_rng(0))
        seen = np.array([dx, 0.0, 0.166])  # the scene places it at (0, 0, 0.16)
        frame = Frame(0.0, {"crate": Detection(seen, tilt)})
        detected = model.memory.record(frame)
        mv = model.move(st, frame, detected, model.memory.perceived(0.0), 0.0, np.random.default_rng(3))
        assert mv.teleported[CRATE] and np.all(mv.depenetrate[:, CRATE]), (dx, aware)
        xy = mv.poses[:, CRATE, :2] - seen[:2]  # the detection plus N(0, 1 cm) per axis, in both cases
        assert np.all(np.abs(xy.mean(axis=0)) < 3 * 0.01 / np.sqrt(200)) and 0.008 < xy.std() < 0.012
        kept = np.array_equal(mv.poses[:, CRATE, 2], st.poses[:, CRATE, 2]) and np.array_equal(
            mv.poses[:, CRATE, 3:], st.poses[:, CRATE, 3:])
        assert kept == level, (dx, aware)
        if not level:  # at the detection's height (with noise) and tilted like it
            assert abs(mv.poses[:, CRATE, 2].mean() - seen[2]) < 3 * 0.01 / np.sqrt(200)
            assert np.all(np.abs(mv.poses[:, CRATE, 3:] @ tilt) > 0.99)


def test_round_objects_rolling_friction_is_scaled_log_uniformly_and_boxes_keep_theirs():
    sc = scene()
    cfg = EstimatorConfig(particles=4000, noise=NoiseConfig())
    memory = PerceptionMemory(sc, initial_poses(sc)[0], cfg.reasoner, cfg.follow_hands)
    base = np.tile([0.5, 0.002, 0.0, 0.1, 0.2], (len(sc.objects), 1))  # every object has one
    st = SceneModel(sc, cfg, base, memory).initial_state(np.random.default_rng(0))
    lo, hi = cfg.noise.rolling_friction_scale
    for m in (BALL, CUP, MYSTERY):  # sphere, cylinder, sphere
        f = np.log(st.params[:, m, 1] / 0.002)
        assert np.all((f >= np.log(lo) - 1e-12) & (f <= np.log(hi) + 1e-12))
        # log-uniform on [log lo, log hi]: mean 0 for (0.5, 2), std (log 4) / sqrt(12)
        sd = np.log(hi / lo) / np.sqrt(12)
        assert abs(f.mean() - np.log(lo * hi) / 2) < 3 * sd / np.sqrt(len(f))
    assert np.all(st.params[:, CRATE, 1] == 0.002) and np.all(st.params[:, TABLE, 1] == 0.002)
    fixed = EstimatorConfig(particles=50, noise=NoiseConfig(rolling_friction_range=(0.0, 0.001)))
    st = SceneModel(sc, fixed, base, memory).initial_state(np.random.default_rng(0))
    assert np.all(st.params[:, [CRATE, BALL], 1] <= 0.001)  # an absolute range replaces the scale


