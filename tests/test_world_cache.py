"""What each particle's world holds (estimator/worlds/world_cache.py)."""
import numpy as np

from estimator.worlds.world_cache import WorldCache


def _state(K=3, M=2, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(K, M, 7)), np.zeros((K, M, 6))


def test_everything_loads_until_the_worlds_hold_something_then_only_what_changed():
    cache = WorldCache()
    poses, vel = _state()
    reset, settled = cache.loads(poses, vel)
    assert reset.all() and settled is None
    cache.hold(poses.copy(), vel.copy())
    moved = poses.copy()
    moved[1, 0, 0] += 0.01
    reset, settled = cache.loads(moved, vel)
    assert reset.tolist() == [[False, False], [True, False], [False, False]]
    # what a world produced at rest, unchanged: may load asleep; the moved entry may not
    assert settled.tolist() == [[True, True], [False, True], [True, True]]
    moving = vel.copy()
    moving[2, 1, 0] = 0.3
    assert not cache.loads(poses, moving)[1][2, 1]


def test_lost_worlds_load_in_full_and_resampling_moves_what_was_produced_not_what_worlds_hold():
    cache = WorldCache()
    poses, vel = _state()
    cache.hold(poses.copy(), vel.copy(), lost=np.array([False, True, False]))
    assert cache.loads(poses, vel)[0].tolist() == [[False, False], [True, True], [False, False]]
    cache.hold(poses.copy(), vel.copy())
    cache.follow(np.array([2, 2, 0]))  # particle 0 and 1 are copies of 2 now, 2 of 0
    copies = poses[[2, 2, 0]]
    reset, settled = cache.loads(copies, vel)
    assert reset.tolist() == [[True, True], [True, True], [True, True]]  # the worlds hold the old ones
    assert settled.all()  # ... but each is a state some world produced at rest: loaded asleep
    # a horizontal Kalman step (fused) keeps a resting entry loadable asleep
    nudged = copies.copy()
    nudged[0, 1, 0] += 0.002
    fused = np.zeros((3, 2), bool)
    assert not cache.loads(nudged, vel)[1][0, 1]
    fused[0, 1] = True
    assert cache.loads(nudged, vel, fused)[1][0, 1]


def test_a_new_particle_count_keeps_the_slots_it_had_and_loads_the_new_ones_in_full():
    cache = WorldCache()
    cache.follow(np.arange(5))  # nothing held yet: nothing to keep
    poses, vel = _state(K=3)
    cache.hold(poses.copy(), vel.copy())
    cache.follow(np.array([0, 1, 2, 0, 1]))  # resampling to five particles
    more, more_vel = np.concatenate([poses, poses[:2]]), np.zeros((5, 2, 6))
    assert cache.loads(more, more_vel)[0].tolist() == [[False, False]] * 3 + [[True, True]] * 2
    cache.follow(np.array([0, 1]))
    assert not cache.loads(poses[:2], vel[:2])[0].any()


def test_entries_carried_at_rest_load_asleep_while_they_stay_where_they_were_carried():
    cache = WorldCache()
    poses, vel = _state()
    cache.hold(poses.copy(), vel.copy())
    after = poses[[2, 2, 0]].copy()
    after[0, 1, :2] += 0.03  # object 1 of particle 0 carried with its support, somewhere no world produced
    mask = np.zeros((3, 2), bool)
    mask[0, 1] = True
    cache.follow(np.array([2, 2, 0]), (mask, after))
    assert cache.loads(after, vel)[1].all()
    cache.hold(poses.copy(), vel.copy())
    cache.follow(np.array([2, 2, 0]))  # not said to be at rest: it is loaded awake
    assert not cache.loads(after, vel)[1][0, 1]
    cache.hold(poses.copy(), vel.copy())
    cache.follow(np.array([2, 2, 0]), (mask, after))
    moved = after.copy()
    moved[0, 1, 2] += 0.01  # moved again before the load: awake
    assert not cache.loads(moved, vel)[1][0, 1]


def test_after_loads_only_what_the_model_placed_at_rest_is_settled_and_its_copies():
    """An update of no steps produces nothing at rest: afterwards only the entries the model placed
    at rest count as settled, unchanged or copied by a resampling, and not once moved (even along
    their support by the fusion). The next update that steps makes everything it leaves at rest
    settled again."""
    cache = WorldCache()
    poses, vel = _state()
    placed = np.array([[True, False], [False, False], [True, True]])
    cache.hold(poses.copy(), vel.copy(), at_rest=placed)
    assert cache.loads(poses, vel)[1].tolist() == placed.tolist()
    cache.follow(np.array([2, 0, 1]))
    copies = poses[[2, 0, 1]]
    reset, settled = cache.loads(copies, vel)
    assert settled.tolist() == placed[[2, 0, 1]].tolist() and reset.all()
    nudged = copies.copy()
    nudged[0, 0, 0] += 0.002
    assert not cache.loads(nudged, vel, np.ones((3, 2), bool))[1][0, 0]
    cache.hold(copies.copy(), vel.copy())
    assert cache.loads(copies, vel)[1].all()
