"""The evidence and the sum of the terms: estimator.model.weighing."""
from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.model.terms import Evidence
from estimator.observations import Frame
from estimator.worlds.pool import BatchOutput
from model_helpers import CUP, TABLE, cup_held_seen_still, make


def test_an_object_physics_let_diverge_is_weighed_at_its_divergence_even_when_put_down_at_once():
    """A cup seen at rest, free in both particles: in particle 1 physics let it diverge 5 cm from its
    detection (the pool put it there and held it), and the update's Place rule lets it go again.
    The evidence still says it diverged, and the particle whose physics agreed weighs more: the
    override does not make particle 1's world look right."""
    model = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    st = model.initial_state(np.random.default_rng(0))
    t, perceived, mv, _, _ = cup_held_seen_still(model, st, 0.14, np.zeros((2, 2, 3)))
    assert mv.check[:, CUP].all() and np.all(mv.modes[:, CUP] == FREE)
    poses = st.poses.copy()
    poses[:, CUP, :3] = [0.3, 0.3, 0.14]  # both end on the detection
    modes = mv.modes.copy()
    modes[1, CUP] = HELD  # particle 1: switched by the divergence test
    divergence = np.zeros((2, 5))
    divergence[:, CUP] = [0.004, 0.05]
    aabbs = np.zeros((2, 5, 2, 3))
    aabbs[:, TABLE] = [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.1]]
    aabbs[:, CUP] = [[0.27, 0.27, 0.1], [0.33, 0.33, 0.18]]
    out = BatchOutput(poses, np.zeros_like(st.velocities), modes, divergence, aabbs, np.ones(2, bool),
                      np.zeros((2, 5)))
    settled = model.settle(st, mv, out, t, 0.08, perceived, perceived)
    assert list(settled.modes[:, CUP]) == [FREE, FREE]  # put down again at once
    assert list(out.modes[:, CUP]) == [FREE, HELD]      # what physics made is left as it was
    ev = model.evidence(mv, settled, out, Frame(t), perceived, perceived, st.unseen_in_view)
    assert np.isnan(ev.diverged[0, CUP]) and ev.diverged[1, CUP] == 0.05
    assert np.isnan(np.delete(ev.diverged, CUP, axis=1)).all()
    lw = model.log_weight(np.zeros(2), ev)
    assert lw[0] > lw[1] + 1.0


def test_log_weight_of_one_particle_is_only_the_explosion_mask():
    model = make(EstimatorConfig(particles=1, noise=NoiseConfig()))
    z = np.zeros((1, 5, 7))
    ev = Evidence(poses=z + 5.0, predicted=z, previous_modes=np.zeros((1, 5), np.int8),
                  modes=np.ones((1, 5), np.int8), detected=np.ones(5, bool), teleported=np.zeros(5, bool),
                  perceived=np.ones(5, bool), detected_poses=np.zeros((5, 7)), has_orientation=np.zeros(5, bool),
                  detection_std=np.full(5, 0.01), visible=np.ones((1, 5)), queried=np.ones(5, bool),
                  in_tracked_hand=np.zeros(5, bool), finite=np.ones(1, bool),
                  unseen_in_view=np.zeros((1, 5), np.int32))
    assert model.log_weight(np.zeros(1), ev)[0] == 0.0
    assert model.log_weight(np.zeros(1), replace(ev, finite=np.zeros(1, bool)))[0] == -np.inf
    two = make(EstimatorConfig(particles=2, noise=NoiseConfig()))
    ev2 = replace(ev, poses=np.concatenate([z, z + 5.0]), predicted=np.concatenate([z, z]),
                  previous_modes=np.zeros((2, 5), np.int8), modes=np.zeros((2, 5), np.int8),
                  visible=np.zeros((2, 5)), finite=np.ones(2, bool))
    lw = two.log_weight(np.zeros(2), ev2)
    assert lw[0] > lw[1] and np.all(np.isfinite(lw))  # with two, the detections weigh
    assert lw[0] == pytest.approx(sum(term(ev2)[0] for term in two.terms))
