"""estimator.model.mechanisms: the list a scene model is built from, and what a new mechanism gets by
being on it (its hooks run, its arrays are kept and resampled without the loop knowing them)."""
import numpy as np

import estimator.model.scene_model as scene_model
from estimator.config import EstimatorConfig, NoiseConfig, default_config
from estimator.filter import SceneEstimator
from estimator.model.mechanisms import PHASES, Mechanism, mechanisms_for
from estimator.model.mechanisms.base import ArraySpec
from estimator.model.mechanisms.flick import LetGoMoving
from estimator.model.mechanisms.rest_fusion import FusionAtRest
from estimator.model.mechanisms.teleport import Teleports
from estimator.model.mechanisms.velocity import VelocityEvidence
from estimator.observations import Frame
from helpers import TABLE_TOP, det, table_scene
from model_helpers import make

FULL_ONLY = (VelocityEvidence, LetGoMoving, FusionAtRest)


def test_the_papers_reasoner_is_a_shorter_list_of_the_same_mechanisms():
    paper = make(EstimatorConfig.paper()).mechanisms
    full = make(default_config(64, "particles")).mechanisms
    assert isinstance(paper[0], Teleports) and isinstance(full[0], Teleports)
    assert not any(isinstance(m, FULL_ONLY) for m in paper)
    assert all(any(isinstance(m, kind) for m in full) for kind in FULL_ONLY)
    assert {type(m) for m in paper} < {type(m) for m in full}
    hooks = {name for m in full for name in PHASES if hasattr(m, name)}
    assert hooks == set(PHASES)  # every phase has a mechanism


class LastAncestor(Mechanism):
    """A mechanism added for the test: each particle records its index at the start of every update
    in an array it declares."""

    arrays = {"was": ArraySpec((), np.int32, -1)}

    def perceive(self, u):
        u.state.was[:] = np.arange(len(u.state.was))[:, None]


def test_a_new_mechanism_is_one_entry_its_hooks_run_and_its_array_is_resampled_with_the_particles(monkeypatch):
    monkeypatch.setattr(scene_model, "mechanisms_for", lambda model: mechanisms_for(model) + [LastAncestor(model)])
    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0, 0, TABLE_TOP + 0.03]}}
    cfg = EstimatorConfig(particles=16, workers=0, noise=NoiseConfig(position_std=0.02), resample_threshold=1.0)
    with SceneEstimator(table_scene(box), cfg, np.random.default_rng(1)) as est:
        assert est.state.was.shape == (16, 2) and est.state.was.dtype == np.int32 and np.all(est.state.was == -1)
        for i, x in enumerate([0.0, 0.01, 0.02]):
            est.update(Frame(0.1 * i, {"box": det([x, 0.0, TABLE_TOP + 0.03])}))
        was = est.state.was[:, 0]
        # after the last update's resampling each particle holds its ancestor's record: copies of one
        # ancestor agree on the box's pose, and the weights picked some particles more than once
        assert len(np.unique(was)) < 16 and np.all((was >= 0) & (was < 16))
        for a in np.unique(was):
            rows = np.flatnonzero(was == a)
            assert np.allclose(est.state.poses[rows, 1, :3], est.state.poses[rows[0], 1, :3], atol=0.0)
