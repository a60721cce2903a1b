"""estimator.model.mechanisms: the list a scene model is built from, and what a new mechanism gets by
being on it (its hooks run, its arrays are kept and resampled without the loop knowing them)."""
import numpy as np
import pytest

from estimator.config import EstimatorConfig, NoiseConfig, default_config
from estimator.filter import SceneEstimator
from estimator.model.mechanisms import PHASES, Mechanism, mechanisms_for
from estimator.model.mechanisms.base import ArraySpec
from estimator.model.mechanisms.deceleration import DecelerationTerm
from estimator.model.mechanisms.flick import LetGoMoving
from estimator.model.mechanisms.rest_fusion import FusionAtRest
from estimator.model.mechanisms.teleport import Teleports
from estimator.model.mechanisms.velocity import VelocityEvidence, VelocityTerm
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
    # a mechanism's terms come with it, after those of every model
    paper_terms = [type(t) for t in make(EstimatorConfig.paper()).terms]
    full_terms = [type(t) for t in make(default_config(64, "particles")).terms]
    assert VelocityTerm not in paper_terms and full_terms == paper_terms + [VelocityTerm, DecelerationTerm]


class LastAncestor(Mechanism):
    """A mechanism added for the test: each particle records its index at the start of every update
    in an array it declares."""

    arrays = {"was": ArraySpec((), np.int32, -1)}

    def perceive(self, u):
        u.state.was[:] = np.arange(len(u.state.was))[:, None]


def test_a_new_mechanism_is_one_entry_its_hooks_run_and_its_array_is_resampled_with_the_particles():
    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0, 0, TABLE_TOP + 0.03]}}
    cfg = EstimatorConfig(particles=16, workers=0, noise=NoiseConfig(position_std=0.02), resample_threshold=1.0)
    with SceneEstimator(table_scene(box), cfg, np.random.default_rng(1),
                        mechanisms=lambda model: mechanisms_for(model) + [LastAncestor(model)]) as est:
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


def _p_held_after_a_lift_out_of_view(drop=None):
    """A box lifted 25 cm off the table and then no longer seen (no hand tracked); P(held) a second
    after it vanished, with the model's mechanisms less ``drop``."""
    def mechanisms(model):
        return [m for m in mechanisms_for(model) if drop is None or not isinstance(m, drop)]

    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0.1, 0, TABLE_TOP + 0.03]}}
    cfg = EstimatorConfig(particles=32, workers=0, noise=NoiseConfig())
    frames = [Frame(t, {"box": det([0.1, 0.0, TABLE_TOP + 0.03 + 0.25 * min(1.0, max(0.0, (t - 0.3) / 0.6))])})
              for t in np.arange(0.0, 1.2, 1 / 30)]
    frames += [Frame(t, {}) for t in np.arange(1.2, 2.2, 1 / 30)]  # gone
    with SceneEstimator(table_scene(box), cfg, np.random.default_rng(2), mechanisms=mechanisms) as est:
        beliefs = est.run(frames)
        return beliefs[-1].objects["box"].p_held


def test_a_mechanism_taken_off_the_list_is_gone_and_nothing_else_breaks():
    """Release on loss is one module and one entry: without it a box lifted out of view is still held
    in every particle a second later; with it, the particles let it go at its rate."""
    from estimator.model.mechanisms.release import ReleaseOnLoss

    assert _p_held_after_a_lift_out_of_view(drop=ReleaseOnLoss) == pytest.approx(1.0, abs=1e-9)
    assert _p_held_after_a_lift_out_of_view() < 0.9
