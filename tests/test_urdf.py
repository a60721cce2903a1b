import os
import xml.etree.ElementTree as ET

import numpy as np
import pybullet_data
import pytest

from helpers import table_scene
from physics.urdf import collision_only_urdf
from physics.world import PhysicsSettings, World

DATA = pybullet_data.getDataPath()


@pytest.mark.parametrize("name", ["table/table.urdf", "objects/mug.urdf", "tray/traybox.urdf", "duck_vhacd.urdf"])
def test_collision_only_copy_has_no_visuals_and_the_same_physics(name):
    src = os.path.join(DATA, name)
    out = collision_only_urdf(src)
    assert out != src and os.path.isfile(out)
    root = ET.parse(out).getroot()
    assert not list(root.iter("visual"))
    assert len(list(root.iter("collision"))) == len(list(ET.parse(src).getroot().iter("collision"))) > 0
    for mesh in root.iter("mesh"):
        assert os.path.isabs(mesh.get("filename")) and os.path.isfile(mesh.get("filename"))
    assert collision_only_urdf(src) == out  # written once
    scene = table_scene({"id": "thing", "urdf": src, "pose": {"position": [0.1, 0, 0.8]}})
    with World(scene) as full, World(scene, PhysicsSettings(collision_only=True)) as bare:
        for w in (full, bare):
            w.step(120)
        assert bare.get_dynamics(1) == full.get_dynamics(1)
        assert np.allclose(bare.get_poses(), full.get_poses(), atol=1e-9)
        assert np.allclose(bare.aabbs(), full.aabbs(), atol=1e-9)


def test_a_file_that_is_not_xml_is_left_to_pybullet(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link")
    assert collision_only_urdf(str(bad)) == str(bad)
    assert collision_only_urdf(str(tmp_path / "missing.urdf")) == str(tmp_path / "missing.urdf")


def test_visual_geometry_copy_collides_as_its_look():
    from physics.urdf import visual_geometry_urdf
    src = os.path.join(DATA, "objects/mug.urdf")
    out = visual_geometry_urdf(src)
    assert out not in (src, collision_only_urdf(src)) and visual_geometry_urdf(src) == out
    root = ET.parse(out).getroot()
    assert not list(root.iter("visual"))
    collisions = list(root.iter("collision"))
    assert len(collisions) == len(list(ET.parse(src).getroot().iter("visual"))) == 1
    assert collisions[0].get("concave") == "yes"
    assert os.path.basename(collisions[0].find("geometry/mesh").get("filename")) == "mug.obj"
    assert all(m.get("value") == "0" for m in root.iter("mass"))
