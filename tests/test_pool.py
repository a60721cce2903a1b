import numpy as np
import pytest

from estimator.pool import BatchInput, WorldPool, shard_bounds

from helpers import TABLE_TOP, table_scene

SCENE = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, TABLE_TOP + 0.2]}})


def batch(k, m, poses):
    return BatchInput(poses=poses, velocities=np.zeros((k, m, 6)), params=np.tile([[0.5, 0, 0, 0, 0.1]], (k, m, 1)),
                      modes=np.zeros((k, m), np.int8), check=np.zeros((k, m), bool), target=poses.copy(),
                      target_vel=np.zeros((k, m, 6)), contents=np.zeros((k, m, m), bool),
                      depenetrate=np.zeros((k, m), bool), reset=np.ones((k, m), bool), vis_query=np.zeros(m, bool))


def test_shards_cover_all_slots():
    assert shard_bounds(10, 3) == [(0, 3), (3, 7), (7, 10)]
    assert shard_bounds(2, 8) == [(0, 1), (1, 2)]


def test_in_process_and_worker_pools_agree_bit_for_bit():
    k, m = 5, 2
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    poses[:, 1, 2] = TABLE_TOP + 0.05 + 0.05 * np.arange(k)  # dropped from different heights
    with WorldPool(SCENE, k, 0) as local, WorldPool(SCENE, k, 2) as remote:
        a = local.run(batch(k, m, poses), 240, 0.045)
        b = remote.run(batch(k, m, poses), 240, 0.045)
        assert np.array_equal(a.poses, b.poses) and np.array_equal(a.aabbs, b.aabbs)
        assert np.allclose(a.poses[:, 1, 2], TABLE_TOP + 0.05, atol=0.002)  # all fell onto the table
        assert np.allclose(local.initial_params, remote.initial_params)
        local.bare_step(3)  # the benchmark's reference stepping, sharded the same way
        remote.bare_step(3)
        c = local.run(batch(k, m, poses), 24, 0.045)
        d = remote.run(batch(k, m, poses), 24, 0.045)
        assert np.array_equal(c.poses, d.poses)


def test_worker_errors_are_reported_and_the_pool_keeps_serving():
    k, m = 4, 2
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    poses[:, 1, 2] = TABLE_TOP + 0.05
    with WorldPool(SCENE, k, 2) as pool:
        with pytest.raises(RuntimeError, match="particle worker failed"):
            pool.run(batch(k, m, poses), "not a number", 0.045)  # fails inside both workers
        out = pool.run(batch(k, m, poses), 24, 0.045)  # every reply was read: the next run works
        assert out.finite.all() and np.allclose(out.poses[:, 1, 2], TABLE_TOP + 0.05, atol=2e-3)


def test_saved_worlds_come_back_after_bare_stepping():
    k, m = 3, 2
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    poses[:, 1, 2] = TABLE_TOP + 0.3  # falling: bare stepping moves it
    for workers in (0, 2):
        with WorldPool(SCENE, k, workers) as pool:
            pool.run(batch(k, m, poses), 10, 0.045)
            keep = np.zeros((k, m), bool)
            b = batch(k, m, poses)
            b.reset = keep  # load nothing: a run of 0 steps reads the worlds back
            before = pool.run(b, 0, 0.045)
            pool.save()
            pool.bare_step(30)
            assert not np.array_equal(pool.run(b, 0, 0.045).poses, before.poses)
            pool.restore()
            after = pool.run(b, 0, 0.045)
            assert np.array_equal(after.poses, before.poses) and np.array_equal(after.velocities, before.velocities)


def test_a_dead_worker_is_a_clear_error():
    k, m = 2, 2
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    with WorldPool(SCENE, k, 2) as pool:
        pool._procs[1].kill()
        pool._procs[1].join()
        with pytest.raises(RuntimeError, match="worker"):
            pool.run(batch(k, m, poses), 5, 0.045)
