"""Long runs: memory that does not grow, and nothing left behind after closing or after a crash."""
import numpy as np
import psutil
import pybullet as pb
import pytest

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.filter import SceneEstimator
from experiments.bench.synthetic import bench_frames, bench_scene


def _clients(est):
    return [g.client for g in est.pool._local.groups]


def test_ten_thousand_updates_keep_memory_flat_and_close_every_client():
    """K = 16, 10 000 reasoning steps (800 s of stream): resident memory after the first thousand
    stays within 20 MB to the end, and closing disconnects every pybullet client."""
    scene = bench_scene(2)
    rng = np.random.default_rng(0)
    cfg = EstimatorConfig(particles=16, workers=0, noise=NoiseConfig())
    me = psutil.Process()
    with SceneEstimator(scene, cfg, rng) as est:
        clients = _clients(est)
        for i, frame in enumerate(bench_frames(scene, 10_000, cfg.reasoner.horizon, rng)):
            est.update(frame)
            if i == 999:
                rss_early = me.memory_info().rss
        rss_late = me.memory_info().rss
        assert est.n_updates == 10_000
        assert all(pb.getConnectionInfo(physicsClientId=c)["isConnected"] for c in clients)
    assert (rss_late - rss_early) / 2**20 < 20
    assert not any(pb.getConnectionInfo(physicsClientId=c)["isConnected"] for c in clients)


def _shm():
    import os
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


def test_a_crash_inside_the_estimator_block_leaves_no_worker_process_behind():
    """The workers exit, and the shared-memory block of the particle arrays leaves nothing in
    /dev/shm (multiprocessing's arena unlinks its file at once)."""
    shm_before = _shm()
    scene = bench_scene(2)
    rng = np.random.default_rng(0)
    cfg = EstimatorConfig(particles=8, workers=2, noise=NoiseConfig())
    with pytest.raises(RuntimeError, match="the caller crashed"):
        with SceneEstimator(scene, cfg, rng) as est:
            pids = est.pool.worker_pids()
            for frame in bench_frames(scene, 5, cfg.reasoner.horizon, rng):
                est.update(frame)
            raise RuntimeError("the caller crashed")
    assert len(pids) == 2 and _shm() <= shm_before
    for pid in pids:
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
