import multiprocessing as mp
import os
import subprocess
import sys

import numpy as np
import psutil
import pytest

import estimator.worlds.pool as pool_module
from estimator.worlds.pool import BatchInput, WorldPool
from estimator.worlds.processes import WORKER_MODULES, start_method, start_worker_server, worker_context
from helpers import TABLE_TOP, table_scene

SCENE = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, TABLE_TOP + 0.2]}},
                    {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.2, 0, TABLE_TOP + 0.3]}})


def _drop(k: int, m: int) -> BatchInput:
    poses = np.zeros((k, m, 7))
    poses[..., 6] = 1
    poses[:, 1, 2] = TABLE_TOP + 0.05 + 0.04 * np.arange(k)  # the box dropped from different heights
    poses[:, 2, :3] = [0.2, 0.0, TABLE_TOP + 0.3]  # the ball falls
    return BatchInput(poses=poses, velocities=np.zeros((k, m, 6)), params=np.tile([[0.5, 0, 0, 0, 0.1]], (k, m, 1)),
                      modes=np.zeros((k, m), np.int8), check=np.zeros((k, m), bool), target=poses.copy(),
                      target_vel=np.zeros((k, m, 6)), contents=np.zeros((k, m, m), bool),
                      depenetrate=np.zeros((k, m), bool), reset=np.ones((k, m), bool), vis_query=np.zeros(m, bool))


def _servers() -> list[psutil.Process]:
    """This process's children that are multiprocessing fork servers."""
    return [p for p in psutil.Process().children() if "forkserver" in " ".join(p.cmdline())]


def test_the_start_method_is_the_fork_server_where_the_platform_has_one():
    if sys.platform.startswith("linux"):  # Linux always has one
        assert start_method() == "forkserver"
    assert start_method() in mp.get_all_start_methods()
    assert worker_context().get_start_method() == start_method()
    assert pool_module._worker_main.__module__ in WORKER_MODULES  # the workers' entry point, imported by the server


@pytest.mark.skipif(start_method() != "forkserver", reason="this platform spawns its workers")
def test_workers_are_forked_from_one_server_started_once():
    start_worker_server()
    start_worker_server()  # a second call finds it running
    servers = _servers()
    assert len(servers) == 1
    with WorldPool(SCENE, 4, 2) as pool:
        parents = {psutil.Process(pid).ppid() for pid in pool.worker_pids()}
        assert parents == {servers[0].pid}  # forked by the server, not by this process (and its threads)
        assert os.getpid() not in parents
    assert len(_servers()) == 1  # still the one server: the next pool forks from it again


def test_a_forked_worker_computes_what_a_spawned_one_does(monkeypatch):
    k, m = 4, 3  # the table, the box, the ball
    with WorldPool(SCENE, k, 2) as pool:
        a = pool.run(_drop(k, m), 120, 0.045)
        a2 = pool.run(_drop(k, m), 24, 0.045)
    monkeypatch.setattr(pool_module, "worker_context", lambda: mp.get_context("spawn"))
    with WorldPool(SCENE, k, 2) as pool:
        b = pool.run(_drop(k, m), 120, 0.045)
        b2 = pool.run(_drop(k, m), 24, 0.045)
    for x, y in ((a, b), (a2, b2)):
        assert np.array_equal(x.poses, y.poses) and np.array_equal(x.velocities, y.velocities)
        assert np.array_equal(x.aabbs, y.aabbs)
    # the boxes fell onto the table, each from its own height (the comparison is not of empty worlds)
    assert np.allclose(a.poses[:, 1, 2], TABLE_TOP + 0.05, atol=0.003)
    assert np.all(a.poses[:, 2, 2] < TABLE_TOP + 0.3 - 0.05)


def test_this_module_imports_nothing_heavy():
    """The command line imports it before its own imports: it must not bring numpy or pybullet in."""
    code = ("import sys; import estimator.worlds.processes; "
            "print(' '.join(m for m in ('numpy', 'pybullet', 'physics') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == ""
