"""The MuJoCo model of a scenario (experiments.simulation.mujoco_model): collision geometry read from
URDF and OBJ files, contact parameters."""
import math
import os

import numpy as np
import pybullet_data
import pytest

from experiments.simulation.mujoco_model import MAX_RESTITUTION, obj_parts, restitution_damping, urdf_geoms

DATA = pybullet_data.getDataPath()


def test_obj_parts_are_the_convex_pieces_of_the_collision_meshes():
    duck = obj_parts(os.path.join(DATA, "duck_vhacd.obj"))
    mug = obj_parts(os.path.join(DATA, "objects", "mug_col.obj"))
    assert len(duck) == 5 and len(mug) == 6  # the files' 'o' objects
    assert all(p.ndim == 2 and p.shape[1] == 3 and len(p) >= 4 for p in duck + mug)
    geoms, mass = urdf_geoms(os.path.join(DATA, "duck_vhacd.urdf"), 2.0)
    assert mass == pytest.approx(0.1) and len(geoms) == 5
    # the URDF's mesh scale (0.05) and the global scaling (2) both apply
    extent = np.ptp(np.concatenate([g["vertices"] for g in geoms]), axis=0)
    assert 0.05 < extent.max() < 0.25
    tray, _ = urdf_geoms(os.path.join(DATA, "tray", "traybox.urdf"))
    assert [g["type"] for g in tray] == ["box"] * 5  # the tray stays five boxes: hollow


def test_restitution_maps_to_the_damping_ratio_of_a_spring_that_bounces_back_as_much():
    assert restitution_damping(0.0) == 1.0
    for e in (0.1, 0.5, 0.8):
        z = restitution_damping(e)
        assert 0 < z < 1
        assert math.exp(-z * math.pi / math.sqrt(1 - z * z)) == pytest.approx(e, rel=1e-9)
    assert restitution_damping(3.0) == restitution_damping(MAX_RESTITUTION)
