import numpy as np
import pytest

from physics.errors import SceneError
from physics.scene import scene_from_dict
from physics.world import FLOOR, World

from helpers import TABLE_TOP, table_scene


def test_static_table_and_falling_primitives():
    scene = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "mass": 0.5,
                         "pose": {"position": [0, 0, 0.8]}},
                        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [1.2, 0, 0.5]}},
                        {"id": "can", "cylinder": {"radius": 0.03, "height": 0.1}, "pose": {"position": [0.3, 0, 0.7]}})
    with World(scene) as w:
        assert w.static.tolist() == [True, False, False, False]
        w.step(480)
        p = w.get_poses()
        assert np.allclose(p[0, :3], 0.0)  # the table did not move: static, not a 60 kg body
        assert p[1, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)
        assert p[2, 2] == pytest.approx(0.03, abs=2e-3)  # ball on the floor
        assert p[3, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)
        assert w.get_dynamics(1)["mass"] == pytest.approx(0.5)
        box = w.aabbs([1])[0]
        assert np.allclose(box[1] - box[0], 0.1, atol=1e-3)


def test_poses_velocities_roundtrip_and_offsets():
    # the mug's URDF frame is at its bottom while its centre of mass is not at the origin of the link
    scene = table_scene({"id": "mug", "urdf": "pybullet_data://objects/mug.urdf", "mass": 0.3,
                         "pose": {"position": [0.2, 0.1, 0.9], "orientation": [0, 0, 0.3826834, 0.9238795]}})
    with World(scene) as w:
        p = w.get_poses([1])
        assert np.allclose(p[0, :3], [0.2, 0.1, 0.9], atol=1e-9)
        new = np.array([[0.1, 0.0, 1.0, 0, 0, 0, 1.0]])
        w.set_poses(new, [1])
        assert np.allclose(w.get_poses([1]), new, atol=1e-9)
        v = np.array([[0.1, -0.2, 0.3, 0.0, 0.0, 2.0]])
        w.set_velocities(v, [1])
        assert np.allclose(w.get_velocities([1]), v, atol=1e-9)
        w.set_dynamics(1, lateral_friction=0.25, restitution=0.1, mass=0.4)
        d = w.get_dynamics(1)
        assert d["lateral_friction"] == pytest.approx(0.25) and d["mass"] == pytest.approx(0.4)


def test_container_holds_a_ball_and_rays():
    scene = table_scene({"id": "box", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01},
                         "pose": {"position": [0, 0, TABLE_TOP + 0.06]}},
                        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0, 0, 0.8]}})
    with World(scene) as w:
        w.step(480)
        ball = w.get_poses([2])[0]
        assert ball[2] == pytest.approx(TABLE_TOP + 0.01 + 0.03, abs=2e-3)  # on the box's floor
        hit, frac = w.ray_test([[0, 0, 2], [1.2, 0, 2], [5, 5, 5]], [[0, 0, 0], [1.2, 0, -1], [6, 6, 6]])
        assert hit.tolist() == [2, FLOOR, -1]
        assert frac[1] == pytest.approx(2 / 3, abs=1e-6) and frac[2] == 1.0


def test_identical_worlds_agree_bit_for_bit():
    scene = table_scene(*[{"id": f"b{i}", "box": {"size": [0.05, 0.05, 0.05]},
                           "pose": {"position": [0.1 * i - 0.2, 0.02 * i, 0.7 + 0.06 * i]}} for i in range(5)])
    with World(scene) as a, World(scene) as b:
        a.step(200)
        b.step(200)
        assert np.array_equal(a.get_poses(), b.get_poses())


def test_unknown_objects_are_parked_and_close_is_explicit():
    scene = table_scene({"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}})
    w = World(scene)
    assert np.linalg.norm(w.get_poses([1])[0, :3]) > 40
    w.close()
    assert w.closed
    w.close()  # twice is fine


def test_bad_urdf_is_a_scene_error(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("this is not xml")
    scene = scene_from_dict({"objects": [{"id": "x", "urdf": str(bad), "pose": {"position": [0, 0, 1]}}]},
                            path=str(tmp_path / "s.yaml"))
    with pytest.raises(SceneError, match="could not load URDF") as e:
        World(scene)
    assert e.value.field == "objects[0].urdf"
