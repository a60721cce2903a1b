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


