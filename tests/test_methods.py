"""The method registry of experiments.evaluation.methods and running the methods on a stream."""
from __future__ import annotations

import numpy as np
import pytest

from estimator.config import EstimatorConfig, NoiseConfig
from experiments.evaluation.methods import (
    METHODS,
    effective_particles,
    get_method,
    method_config,
    run_method,
)
from helpers import TABLE_TOP, frames, table_scene

CUP = {"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "mass": 0.2,
       "pose": {"position": [0.1, 0.0, TABLE_TOP + 0.05]}}
BALL = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
        "pose": {"position": [-0.2, 0.1, TABLE_TOP + 0.03]}}


def test_registry_has_the_baselines_the_estimator_and_the_ablations():
    assert list(METHODS) == ["last-seen", "paper", "particles", "particles-no-params", "particles-no-held",
                             "particles-no-negative", "tracker", "tracker-feedback", "particles-on-tracker"]
    with pytest.raises(ValueError, match="known"):
        get_method("kalman")


def test_configs_of_the_methods():
    assert method_config("last-seen", 64) is None
    assert effective_particles("last-seen", 64) == 0
    paper = method_config("paper", 64)
    assert paper.paper_mode and paper.particles == 1 and effective_particles("paper", 64) == 1
    full = method_config("particles", 32)
    assert full.particles == 32 and full.workers == 0 and full.noise == NoiseConfig()
    assert full.negative_evidence and full.follow_hands and full.priors.release_on_loss < 1.0
    no_params = method_config("particles-no-params", 32).noise
    assert all(getattr(no_params, f) is None for f in ("friction_range", "rolling_friction_range",
                                                         "spinning_friction_range", "restitution_range",
                                                         "mass_scale_range"))
    assert no_params.position_std == NoiseConfig().position_std  # only the parameters change
    no_held = method_config("particles-no-held", 32)
    assert no_held.priors.release_on_loss == 1.0 and not no_held.follow_hands
    assert not method_config("particles-no-negative", 32).negative_evidence
    for name in METHODS:
        cfg = method_config(name, 8)
        assert cfg is None or isinstance(cfg, EstimatorConfig)


def _cup_vanishes(t):
    """The cup is seen at rest until 0.5 s, then at 0.3 m to the side until 1.0 s, then never."""
    if t < 0.5:
        return {"cup": [0.1, 0.0, TABLE_TOP + 0.05], "ball": [-0.2, 0.1, TABLE_TOP + 0.03]}
    if t < 1.0:
        return {"cup": [0.1, 0.3, TABLE_TOP + 0.05], "ball": [-0.2, 0.1, TABLE_TOP + 0.03]}
    return {"ball": [-0.2, 0.1, TABLE_TOP + 0.03]}


def test_all_methods_reason_at_the_same_instants():
    scene = table_scene(CUP, BALL)
    frs = frames(np.arange(1, 40) / 30.0, _cup_vanishes)
    base = run_method("last-seen", scene, frs, 4, np.random.default_rng(0))
    paper = run_method("paper", scene, frs, 4, np.random.default_rng(0))
    parts = run_method("particles", scene, frs, 4, np.random.default_rng(0), keep_particles=True)
    times = [s.t for s in paper.steps]
    assert [s.t for s in base.steps] == times == [s.t for s in parts.steps]
    assert len(base.step_seconds) == len(times) and base.events == [] and base.particles == 0
    assert paper.particles == 1 and parts.particles == 4
    assert parts.steps[-1].particles.shape == (4, 3, 3) and parts.steps[-1].weights.shape == (4,)
    assert parts.steps[0].particles is None  # only the last step keeps its cloud


def test_run_method_is_reproducible_with_the_same_generator():
    scene = table_scene(CUP, BALL)
    frs = frames(np.arange(1, 40) / 30.0, _cup_vanishes)
    a = run_method("particles", scene, frs, 4, np.random.default_rng(3))
    b = run_method("particles", scene, frs, 4, np.random.default_rng(3))
    for sa, sb in zip(a.steps, b.steps):
        np.testing.assert_array_equal(sa.positions, sb.positions)
        np.testing.assert_array_equal(sa.covariances, sb.covariances)
    assert a.events == b.events


def test_the_adaptive_count_is_a_particle_count_of_its_own():
    from estimator.config import AdaptiveConfig
    from experiments.evaluation.methods import AUTO, method_config, method_label
    from experiments.evaluation.trials import TrialSpec

    cfg = method_config("particles", AUTO)
    assert cfg.adaptive.enabled and cfg.particles == AdaptiveConfig().min_particles == 164 and cfg.workers == 0
    assert not method_config("particles", 64).adaptive.enabled
    assert not method_config("paper", AUTO).adaptive.enabled  # the paper's reasoner stays one world
    assert method_label("particles", AUTO) == "particles (K=auto)"
    assert "__Kauto__" in TrialSpec("cup_falls_behind_box", 0, "particles", AUTO).key
