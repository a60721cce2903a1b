"""physics.hollow: whether an object may contain others, from its geometry."""
import os

import pybullet as pb
import pybullet_data
import pytest

from physics.bodies import collision_shape
from physics.hollow import body_is_open, urdf_is_open
from physics.scene import ObjectSpec, scene_from_dict

DATA = pybullet_data.getDataPath()


def _scene(static, **extra):
    objects = [
        {"id": "table", "urdf": "pybullet_data://table/table.urdf", "pose": {"position": [0, 0, 0]}},
        {"id": "tray", "urdf": "pybullet_data://tray/traybox.urdf", "pose": {"position": [0, 0, 0.63]}},
        {"id": "mug", "urdf": "pybullet_data://objects/mug.urdf", "pose": {"position": [0.2, 0, 0.63]}},
        {"id": "cube", "urdf": "pybullet_data://cube_small.urdf", "pose": {"position": [-0.2, 0, 0.66]}},
        {"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0.3, 0.3, 0.7]}},
        {"id": "bin", "container": {"size": [0.2, 0.2, 0.1]}, "pose": {"position": [-0.3, 0.3, 0.7]}},
    ]
    for o in objects:
        o["static"] = static
        o.update(extra.get(o["id"], {}))
    return scene_from_dict({"name": "hollow", "objects": objects})


@pytest.mark.parametrize("static", [False, True])
def test_tray_and_mug_are_hollow_table_cube_and_box_are_not_static_or_not(static):
    scene = _scene(static)
    assert dict(zip(scene.object_ids, scene.hollow)) == {
        "table": False, "tray": True, "mug": True, "cube": False, "box": False, "bin": True}


def test_the_scene_file_overrides_the_geometry_and_round_trips():
    scene = _scene(True, table={"hollow": True}, mug={"hollow": False})
    assert scene.hollow == (True, True, False, False, False, True)
    assert scene_from_dict(scene.to_dict()).hollow == scene.hollow


@pytest.mark.parametrize("name, scale, expected", [
    ("tray/traybox.urdf", 0.5, True), ("tray/tray.urdf", 1.0, True), ("objects/mug.urdf", 2.0, True),
    ("table/table.urdf", 1.0, False), ("sphere_small.urdf", 1.0, False), ("jenga/jenga.urdf", 1.0, False),
    # a dip in its back under the middle, but nothing round it: not open
    ("duck_vhacd.urdf", 1.0, False),
    # studs on top are no walls
    ("lego/lego.urdf", 1.0, False),
])
def test_pybullet_data_models(name, scale, expected):
    assert urdf_is_open(os.path.join(DATA, name), scale) is expected


def test_the_mug_is_open_only_in_its_visual_geometry():
    # pybullet_data's mug collides as a closed hull; its look decides
    client = pb.connect(pb.DIRECT)
    try:
        uid = pb.loadURDF(os.path.join(DATA, "objects/mug.urdf"), useFixedBase=True, physicsClientId=client)
        assert not body_is_open(client, uid)
    finally:
        pb.disconnect(physicsClientId=client)
    assert urdf_is_open(os.path.join(DATA, "objects/mug.urdf"))


@pytest.mark.parametrize("spec, expected", [
    (ObjectSpec("bin", "container", size=(0.3, 0.2, 0.12), wall=0.01), True),
    (ObjectSpec("tray", "container", size=(0.3, 0.2, 0.02), wall=0.01), True),  # a 1 cm rim is a tray
    (ObjectSpec("box", "box", size=(0.3, 0.2, 0.12)), False),
    (ObjectSpec("can", "cylinder", radius=0.03, height=0.12), False),
])
def test_the_ray_probe_agrees_with_primitive_shapes(spec, expected):
    client = pb.connect(pb.DIRECT)
    try:
        uid = pb.createMultiBody(0, collision_shape(client, spec), physicsClientId=client)
        assert body_is_open(client, uid) is expected
    finally:
        pb.disconnect(physicsClientId=client)


def test_a_file_pybullet_cannot_load_is_not_open(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link")
    assert urdf_is_open(str(bad)) is False
    assert urdf_is_open(str(tmp_path / "missing.urdf")) is False
