"""estimator.model.mechanisms.deceleration: an object seen rolling along its support is weighed on the
deceleration each particle's physics gave it against the one fitted through its detections."""
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
from test_filter import _rolled_ball

from actions.modes import HELD
from estimator.config import EstimatorConfig, NoiseConfig, default_config
from estimator.filter import SceneEstimator
from estimator.model.mechanisms.deceleration import DecelerationEvidence, DecelerationTerm
from estimator.observations import Detection, Frame
from model_helpers import BALL, make

DECEL = 0.6  # m/s^2, the ball's true deceleration along x


def _rolling_ball(config, particle_decel, seed=3):
    """The ball seen at 30 Hz rolling along x from 1 m/s, slowing down at :data:`DECEL`, with 2 mm of
    noise, reasoned on every 0.1 s for 1 s. At every update particle k's physics had slowed it
    down at ``particle_decel[k]`` (m/s^2) over the last one (its velocity at the start of that update
    is the state's ``roll_v0``); particle 2 holds it. Returns the model, its mechanism and the
    evidence's modes."""
    model = make(config)
    mech = next(m for m in model.mechanisms if isinstance(m, DecelerationEvidence))
    st = model.initial_state(np.random.default_rng(0))
    st.modes[2, BALL] = HELD
    mem, rng = model.memory, np.random.default_rng(seed)
    dt, decel = 0.1, np.asarray(particle_decel, float)
    frames = np.arange(0, 31)
    for j in range(10):
        for f in frames[(frames >= 3 * j) & (frames < 3 * j + 3)]:
            tf = f / 30
            x = 0.08 + 1.0 * tf - 0.5 * DECEL * tf * tf
            mem.record(Frame(tf, {"ball": Detection(np.array([x, 0.0, 0.14]) + rng.normal(0, 0.002, 3))}))
        t = (3 * j + 2) / 30
        v = 1.0 - DECEL * t
        st.roll_v0[:, BALL] = [v + 0.0, 0.0]
        st.velocities[:, BALL, 0] = v - decel * dt
        detected = np.zeros(5, bool)
        detected[BALL] = True
        perceived = mem.perceived(t)
        model.move(st, Frame(t), detected, perceived, dt, np.random.default_rng(j))
        mech._dt_prev = dt  # what its commit records after an update of dt
        mem.end_tick(perceived, detected, mem.tick_velocity())
    return model, mech, st.modes


def test_a_ball_seen_rolling_is_weighed_on_the_deceleration_its_particles_physics_gave_it():
    config = EstimatorConfig(particles=3, noise=NoiseConfig(position_std=0.002))
    model, mech, modes = _rolling_ball(config, [DECEL, 0.2, DECEL])
    mask, accel, seen, std, temper = mech.weighed
    assert mask[:, BALL].tolist() == [True, True, False] and not mask[:, :BALL].any()  # held in 2
    assert np.allclose(accel[:, BALL, 0], [-DECEL, -0.2, -DECEL]) and np.allclose(accel[:, BALL, 1], 0.0)
    fit_se = math.sqrt(std[BALL] ** 2 - (0.1 * np.linalg.norm(seen[BALL])) ** 2 - 0.02 ** 2)
    assert abs(seen[BALL, 0] + DECEL) < 3 * fit_se and abs(seen[BALL, 1]) < 3 * fit_se
    assert 0 < temper[BALL] < 1  # most of what the fit says was weighed at earlier updates
    term = next(t for t in model.terms if isinstance(t, DecelerationTerm))

    logw = term(SimpleNamespace(poses=np.zeros((3, 5, 7)), modes=modes))
    assert logw[0] > logw[1] + 1.0  # the physics that slowed it down as seen wins
    assert logw[1] < logw[2] < logw[0]  # held there: neither for nor against (the mean of the others)


def test_no_deceleration_evidence_without_its_error_or_in_the_papers_mode():
    for config in (EstimatorConfig(particles=3, noise=NoiseConfig(decel_error=0.0)), EstimatorConfig.paper()):
        assert not any(isinstance(m, DecelerationEvidence) for m in make(config).mechanisms)


def test_the_rolling_friction_posterior_is_nearer_the_truth_with_the_deceleration_evidence():
    """The ball's rolling friction is 0.4 times what the scene states (under the prior's factor of
    two); it is seen rolling for 0.7 s. With the deceleration evidence the posterior mean of its
    rolling friction in the estimate stream is nearer the truth (in log) than with the velocity
    evidence alone, for each of three seeds of the filter."""
    scene, frames, nominal = _rolled_ball(0.4)
    frames = [f for f in frames if f.t <= 1.0]
    for seed in (1, 2, 3):
        errors = []
        for decel_error in (0.1, 0.0):
            cfg = replace(default_config(64), workers=0)
            cfg = replace(cfg, noise=replace(cfg.noise, decel_error=decel_error))
            with SceneEstimator(scene, cfg, np.random.default_rng(seed)) as est:
                mean, _ = est.run(frames)[-1].objects["ball"].parameters["rolling_friction"]
            errors.append(abs(math.log(mean / (0.4 * nominal))))
        assert errors[0] < errors[1], (seed, errors)
