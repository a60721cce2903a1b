"""Process noise: estimator.model.mechanisms.process_noise."""
import numpy as np

from actions.modes import HELD
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.process_noise import ProcessNoise
from model_helpers import BALL, CRATE, CUP, make


def test_process_noise_touches_only_unperceived_free_known_dynamic_objects():
    nz = NoiseConfig(process_position_std=0.01, process_orientation_std=0.1, motion_noise=0.5)
    model = make(EstimatorConfig(particles=4, noise=nz))
    st = model.initial_state(np.random.default_rng(0))
    poses = st.poses.copy()
    modes = st.modes.copy()
    modes[:, CUP] = HELD    # held: moved by its hand, not by noise
    modes[3, BALL] = HELD   # the ball is held in particle 3 only
    perceived = np.zeros(5, bool)
    perceived[CRATE] = True
    supported = np.ones((4, 5), bool)
    resting = np.zeros((4, 5), bool)
    resting[2, BALL] = True  # at rest on its support in particle 2: a resting object does not wander
    last_motion = np.zeros((4, 5))
    last_motion[0, BALL] = 0.1  # rolled 10 cm: large model error, capped
    jolted = model.mechanism(ProcessNoise).process_noise(poses, modes, perceived, supported, resting, last_motion, 0.5,
                                 np.random.default_rng(4))
    changed = np.any(poses != st.poses, axis=-1)
    expect = np.zeros((4, 5), bool)
    expect[:2, BALL] = True  # not the static table, the perceived crate, the held cup, the unknown mystery
    assert np.array_equal(changed, expect)
    assert np.all(np.any(poses[:2, BALL, 3:] != st.poses[:2, BALL, 3:], axis=-1))  # orientations too
    assert np.allclose(np.linalg.norm(poses[..., 3:], axis=-1), 1.0)
    # std: sqrt(0.01^2 * 0.5 + (0.5 * rolled)^2) capped at max_jitter_std (0.01); jolted above 2 mm
    assert np.array_equal(jolted, expect)
    assert np.all(np.abs(poses[0, BALL, :3] - st.poses[0, BALL, :3]) < 5 * nz.max_jitter_std)
