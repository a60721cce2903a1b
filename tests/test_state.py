"""The particle state: taking ancestors copies every per-particle array and resets the weights."""
import numpy as np

from estimator.state import ParticleState


def state(K=3, M=2):
    rng = np.random.default_rng(0)
    return ParticleState(poses=rng.normal(size=(K, M, 7)), velocities=rng.normal(size=(K, M, 6)),
                         params=rng.uniform(size=(K, M, 5)), modes=rng.integers(0, 2, (K, M)).astype(np.int8),
                         log_weights=np.array([0.0, -1.0, -2.0]), on_top=rng.uniform(size=(K, M, M + 1)) > 0.5,
                         is_in=rng.uniform(size=(K, M, M)) > 0.5, event_t=rng.normal(size=(K, M, 4)),
                         supported=rng.uniform(size=(K, M)) > 0.5, last_motion=rng.uniform(size=(K, M)),
                         jolted=rng.uniform(size=(K, M)) > 0.5,
                         unseen_in_view=rng.integers(0, 5, (K, M)).astype(np.int32),
                         hold_error=rng.normal(size=(K, M, 3)), let_go_unseen=rng.normal(size=(K, M)),
                         hidden_at=rng.normal(size=(K, M, 3)), hidden_t=rng.normal(size=(K, M)),
                         hidden_n=rng.integers(0, 5, (K, M)).astype(np.int32),
                         down_at=rng.normal(size=(K, M, 3)), down_t=rng.normal(size=(K, M)),
                         rest_at=rng.normal(size=(K, M, 3)), rest_t=rng.normal(size=(K, M)),
                         push_decided=rng.normal(size=(K, M)), holds=rng.normal(size=(K, M, 5)), jitter=rng.normal(size=(K, M, 3)),
                         push_grip=rng.random((K, M)))


def test_take_follows_the_ancestors_and_equalises_the_weights():
    s = state()
    anc = np.array([2, 2, 0])
    t = s.take(anc)
    for name in ("poses", "velocities", "params", "modes", "on_top", "is_in", "event_t", "supported",
                 "last_motion", "jolted", "unseen_in_view", "hold_error", "let_go_unseen", "hidden_at", "hidden_t",
                 "hidden_n", "rest_at", "rest_t", "push_decided", "holds"):
        a, b = getattr(t, name), getattr(s, name)
        assert a.dtype == b.dtype and np.array_equal(a, b[anc]), name
    assert np.all(t.log_weights == 0) and len(t.log_weights) == 3
    t.poses[0, 0, 0] = 99.0
    assert s.poses[2, 0, 0] != 99.0 and t.poses[1, 0, 0] != 99.0  # copies, not views


def test_objects_nothing_weighed_keep_their_own_values_and_ride_their_support():
    """``take(anc, own)``: the object in ``own`` keeps each particle's own pose, velocity and
    parameters (its spread survives weights that pick one particle); one in a container is carried
    from the container's pose in its particle to the ancestor's; the others follow the ancestors."""
    from physics.transforms import carry_pose

    s = state(K=3, M=3)
    s.poses[..., 3:] = [0.0, 0.0, 0.0, 1.0]
    s.on_top[:] = False
    s.is_in[:] = False
    s.is_in[:, 2, 1] = True  # object 2 in object 1 in every particle
    anc = np.array([0, 0, 0])
    before = s.poses.copy()
    t = s.take(anc, own=np.array([True, False, True]))
    assert np.array_equal(t.poses[:, 0], before[:, 0]) and np.array_equal(t.params[:, 0], s.params[:, 0])
    assert np.array_equal(t.velocities[:, 0], s.velocities[:, 0])
    assert np.array_equal(t.poses[:, 1], before[[0, 0, 0], 1])  # the container: resampled
    for k in range(3):
        assert np.allclose(t.poses[k, 2], carry_pose(before[k, 2], before[k, 1], before[0, 1]))
    assert np.array_equal(s.take(anc).poses[:, 0], before[[0, 0, 0], 0])  # without own: the ancestors


def test_take_to_more_or_fewer_particles_keeps_own_values_where_a_particle_was():
    s = state(K=3, M=3)
    s.poses[..., 3:] = [0.0, 0.0, 0.0, 1.0]
    s.on_top[:] = False
    s.is_in[:] = False
    own = np.array([True, False, False])
    more = s.take(np.array([1, 1, 2, 2, 0]), own)
    assert len(more.log_weights) == 5 and more.poses.shape == (5, 3, 7)
    assert np.array_equal(more.poses[:3, 0], s.poses[:, 0])  # rows that had a particle: its own
    assert np.array_equal(more.poses[3:, 0], s.poses[[2, 0], 0])  # the new ones: the ancestor's
    assert np.array_equal(more.poses[:, 1], s.poses[[1, 1, 2, 2, 0], 1])
    fewer = s.take(np.array([2]), own)
    assert fewer.poses.shape == (1, 3, 7) and np.array_equal(fewer.poses[0, 0], s.poses[0, 0])
