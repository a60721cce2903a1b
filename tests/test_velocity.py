"""estimator.model.mechanisms.velocity: an object seen rolling along its support is weighed on the
velocity each particle's physics gave it."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.mechanisms.velocity import VelocityEvidence
from estimator.observations import Detection, Frame
from model_helpers import BALL, make


def _rolling_ball_moves(config):
    """The ball seen rolling along x at 0.9 m/s over three updates; particles 0 and 1 have it rolling
    at 0.3 m/s, particle 2 at rest. Returns the last update's move."""
    model = make(config)
    st = model.initial_state(np.random.default_rng(0))
    mem = model.memory
    for j, t in enumerate([0.0, 0.1, 0.2]):
        st.velocities[:2, BALL] = [0.3, 0.0, 0.0, 0.0, 10.0, 0.0]
        for f in range(3):
            tf = t + f / 30
            mem.record(Frame(tf, {"ball": Detection(np.array([0.08 + 0.9 * tf, 0.0, 0.14]))}))
        frame = Frame(t + 2 / 30)
        detected = np.zeros(5, bool)
        detected[BALL] = True
        perceived = mem.perceived(frame.t)
        mv = model.move(st, frame, detected, perceived, 0.1, np.random.default_rng(j))
        mem.end_tick(perceived, detected, mem.tick_velocity())
    return model, mv


def test_a_ball_seen_rolling_along_is_checked_against_each_particles_velocity_before_the_update():
    model, mv = _rolling_ball_moves(EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.0,
                                                                                   velocity_slack=0.05)))
    assert any(isinstance(m, VelocityEvidence) for m in model.mechanisms)
    mask, predicted, seen, std = model.mechanism(VelocityEvidence).checked
    assert mask[:, BALL].tolist() == [True, True, True] and not mask[:, :BALL].any()
    assert np.allclose(predicted[:, BALL], [[0.3, 0.0], [0.3, 0.0], [0.0, 0.0]])  # before the teleport
    assert np.allclose(seen[BALL], [0.9, 0.0], atol=1e-9) and std.shape == (5,)


def test_no_velocity_evidence_without_slack_or_in_the_papers_mode():
    for config in (EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.0, velocity_slack=0.0)),
                   EstimatorConfig.paper()):
        model, _ = _rolling_ball_moves(config)
        assert not any(isinstance(m, VelocityEvidence) for m in model.mechanisms)
