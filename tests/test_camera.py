"""Synthetic camera: visibility by batched ray tests, frustum, occlusion by scene objects and by
bodies outside the scene (the hand)."""
import numpy as np
import pybullet as pb
import pytest

from experiments.simulation.camera import SyntheticCamera, sample_points
from physics.scene import ObjectSpec, scene_from_dict
from physics.world import World

TABLE = {"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
         "pose": {"position": [0, 0, 0]}}
SIDE_CAMERA = {"position": [1.2, 0.0, 0.9], "target": [0.0, 0.0, 0.7], "fov_deg": 60}


def _world(objects, camera=SIDE_CAMERA):
    scene = scene_from_dict({"camera": camera, "objects": [TABLE] + objects})
    return World(scene)


def _cup(x, y=0.0):
    return {"id": "cup", "cylinder": {"radius": 0.035, "height": 0.1}, "pose": {"position": [x, y, 0.676]}}


def test_object_in_plain_view_is_visible():
    with _world([_cup(0.0)]) as w:
        cam = SyntheticCamera(w, w.scene.camera)
        frac = cam.visible_fractions()
        assert frac[w.index("cup")] > 0.9
        assert cam.visible()[w.index("cup")]


def test_object_behind_a_box_is_not_visible_but_beside_it_is():
    box = {"id": "box", "box": {"size": [0.1, 0.25, 0.2]}, "pose": {"position": [0.1, 0.0, 0.726]}}
    with _world([box, _cup(-0.05)]) as w:
        cam = SyntheticCamera(w, w.scene.camera)
        assert cam.visible_fractions()[w.index("cup")] == 0.0
        assert cam.visible()[w.index("box")]
    with _world([box, _cup(-0.05, 0.35)]) as w:
        assert SyntheticCamera(w, w.scene.camera).visible()[w.index("cup")]


def test_a_camera_moved_behind_the_box_sees_the_cup_with_the_same_sample_points():
    from physics.scene import CameraSpec

    box = {"id": "box", "box": {"size": [0.1, 0.25, 0.2]}, "pose": {"position": [0.1, 0.0, 0.726]}}
    with _world([box, _cup(-0.05)]) as w:
        cam = SyntheticCamera(w, w.scene.camera)
        behind = cam.moved_to(CameraSpec(position=(-1.0, 0.0, 0.9), target=(0.0, 0.0, 0.7)))
        assert cam.visible_fractions()[w.index("cup")] == 0.0  # the original is unchanged
        assert behind.visible_fractions()[w.index("cup")] > 0.9
        assert behind.points is cam.points and behind.threshold == cam.threshold
        same = cam.moved_to(w.scene.camera)
        assert np.array_equal(same.visible_fractions(), cam.visible_fractions())


def test_partly_hidden_object_has_intermediate_fraction():
    box = {"id": "box", "box": {"size": [0.1, 0.25, 0.2]}, "pose": {"position": [0.1, 0.0, 0.726]}}
    with _world([box, _cup(-0.05, 0.13)]) as w:
        f = SyntheticCamera(w, w.scene.camera).visible_fractions()[w.index("cup")]
        assert 0.05 < f < 0.95


def test_ball_inside_container_hidden_from_the_side_visible_from_above():
    objs = [{"id": "bin", "container": {"size": [0.2, 0.2, 0.14], "wall": 0.01},
             "pose": {"position": [0.0, 0.0, 0.696]}},
            {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.0, 0.0, 0.666]}}]
    with _world(objs) as w:
        cam = SyntheticCamera(w, w.scene.camera)
        vis = cam.visible()
        assert vis[w.index("bin")] and not vis[w.index("ball")]
    top = {"position": [0.05, 0.0, 1.6], "target": [0.0, 0.0, 0.6], "fov_deg": 60}
    with _world(objs, camera=top) as w:
        assert SyntheticCamera(w, w.scene.camera).visible()[w.index("ball")]


def test_outside_the_field_of_view_is_not_visible():
    narrow = {"position": [1.2, 0.0, 0.9], "target": [0.0, 0.0, 0.7], "fov_deg": 10}
    with _world([_cup(0.0, 0.45)], camera=narrow) as w:
        assert SyntheticCamera(w, w.scene.camera).visible_fractions()[w.index("cup")] == 0.0
    far = {"position": [1.2, 0.0, 0.9], "target": [0.0, 0.0, 0.7], "fov_deg": 60, "far": 0.8}
    with _world([_cup(0.0)], camera=far) as w:
        assert SyntheticCamera(w, w.scene.camera).visible_fractions()[w.index("cup")] == 0.0


def test_a_body_outside_the_scene_occludes():
    with _world([_cup(0.0)]) as w:
        cam = SyntheticCamera(w, w.scene.camera)
        assert cam.visible()[w.index("cup")]
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.09, physicsClientId=w.client)
        pb.createMultiBody(0, shape, -1, [0.3, 0.0, 0.74], physicsClientId=w.client)
        assert cam.visible_fractions()[w.index("cup")] < 0.3
        assert not cam.visible()[w.index("cup")]


def test_sample_points_are_fixed_and_inside_the_geometry():
    spec = ObjectSpec(id="b", shape="box", size=(0.1, 0.2, 0.3))
    a, b = sample_points(spec, 64), sample_points(spec, 64)
    assert np.array_equal(a, b)
    assert np.all(np.abs(a) <= np.array([0.05, 0.1, 0.15]))
    s = sample_points(ObjectSpec(id="s", shape="sphere", radius=0.05), 64)
    assert np.all(np.linalg.norm(s, axis=1) <= 0.05)
    c = sample_points(ObjectSpec(id="c", shape="container", size=(0.2, 0.2, 0.1), wall=0.01), 200)
    inner = (np.abs(c[:, 0]) < 0.09) & (np.abs(c[:, 1]) < 0.09) & (c[:, 2] > -0.04)
    assert not inner.any()  # on the walls and floor, never in the cavity
    with pytest.raises(ValueError):
        sample_points(ObjectSpec(id="u", shape="urdf", urdf="x.urdf"), 8)


def test_urdf_objects_are_seen():
    objs = [{"id": "mug", "urdf": "pybullet_data://objects/mug.urdf", "pose": {"position": [0, 0.0, 0.63]}},
            {"id": "duck", "urdf": "pybullet_data://duck_vhacd.urdf", "pose": {"position": [0.1, -0.2, 0.66]}}]
    with _world(objs) as w:
        w.step(30)
        assert SyntheticCamera(w, w.scene.camera).visible().all()
