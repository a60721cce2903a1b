import numpy as np
import pytest

from helpers import TABLE_TOP, table_scene
from physics.errors import SceneError
from physics.scene import scene_from_dict
from physics.settings import PhysicsSettings
from physics.sleep import sleep, touching, wake
from physics.world import FLOOR, World


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
    # the teddy's centre of mass is 9 cm off the origin of its link frame
    scene = table_scene({"id": "teddy", "urdf": "pybullet_data://teddy_vhacd.urdf", "mass": 0.3,
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
        w.set_poses(new + [[0.05, 0, 0, 0, 0, 0, 0]], [1])  # a teleport keeps the velocity (pybullet's zeroes it)
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


def test_raw_read_back_and_frame_conversions_agree_with_the_named_access():
    # a URDF whose centre of mass is off its link frame (the teddy) next to a primitive and the table
    scene = table_scene({"id": "teddy", "urdf": "pybullet_data://teddy_vhacd.urdf", "mass": 0.3,
                         "pose": {"position": [0.2, 0.1, 0.9], "orientation": [0, 0, 0.3826834, 0.9238795]}},
                        {"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [-0.2, 0, 0.9]}})
    with World(scene) as w:
        v = np.array([[0.1, -0.2, 0.3, 0.5, 0.0, 2.0], [0.0, 0.3, 0.0, 0.0, 1.0, 0.0]])
        w.set_velocities(v, [1, 2])
        w.step(3)
        p, vel, boxes = w.read_state()
        assert np.allclose(p, w.get_poses(), atol=1e-12) and np.allclose(vel, w.get_velocities(), atol=1e-12)
        assert np.allclose(boxes, w.aabbs())
        raw_p, raw_v, _ = w.read_raw(range(w.num_objects))
        com_p, com_v = np.array(raw_p).reshape(-1, 7), np.array(raw_v).reshape(-1, 6)
        assert not np.allclose(com_p[1, :3], p[1, :3], atol=1e-3)  # the offset is real
        # the conversions are inverse to each other, for stacks of particles too
        stack_p, stack_v = np.stack([p, p]), np.stack([vel, vel])
        back_p, back_v = w.link_frame(*w.com_frame(stack_p, stack_v))
        assert np.allclose(back_p, stack_p, atol=1e-12) and np.allclose(back_v, stack_v, atol=1e-12)
        assert np.allclose(w.com_frame(p, vel)[0], com_p, atol=1e-12)
        # loading centre-of-mass state puts the objects back exactly where they were read
        w.step(10)
        w.load_com_state([1, 2], com_p[1:].tolist(), com_v[1:].tolist())
        assert np.allclose(w.get_poses([1, 2]), p[1:], atol=1e-12)
        assert np.allclose(w.get_velocities([1, 2]), vel[1:], atol=1e-12)
        sp, sb = w.static_raw()
        assert np.allclose(sp[0], com_p[0]) and np.allclose(sb[0], boxes[0]) and np.isnan(sp[1:]).all()
        # saved states come back exactly and are freed
        sid = w.save_state()
        before = w.get_poses()
        w.step(20)
        w.restore_state(sid)
        w.remove_state(sid)
        assert np.array_equal(w.get_poses(), before)


@pytest.mark.parametrize("surface, lo, hi", [(None, -0.005, 0.01), (0.5, 0.05, 0.2), (1.0, 0.25, 0.45)])
def test_restitution_is_the_product_of_the_two_bodies(surface, lo, hi):
    """Bullet multiplies the restitutions at a contact: a ball of 0.8 dropped from 0.47 m above a slab
    bounces (its centre rises above the rest height) under 1 cm when the slab has none, about
    (0.8 x 0.5)^2 x 0.47 m with 0.5 and (0.8)^2 x 0.47 m with 1 (the README's scene-format note)."""
    slab = {"id": "slab", "static": True, "box": {"size": [1.0, 1.0, 0.1]}, "pose": {"position": [0, 0, -0.05]}}
    if surface is not None:
        slab["restitution"] = surface
    scene = scene_from_dict({"floor": False, "objects": [
        slab, {"id": "ball", "sphere": {"radius": 0.03}, "restitution": 0.8, "pose": {"position": [0, 0, 0.5]}}]})
    with World(scene) as w:
        landed, top = False, 0.0
        for _ in range(480):
            w.step(1)
            z = w.get_poses([1])[0, 2]
            landed = landed or z < 0.035
            top = max(top, z) if landed else top
        assert lo < top - 0.03 < hi


def _rolling_speeds(rolling_friction, v0=1.0, seconds=0.5):
    """Speeds (m/s) of a 3 cm ball set rolling without slipping along the table at ``v0``, every
    0.1 s for ``seconds``."""
    ball = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
            "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.03]}}
    if rolling_friction is not None:
        ball["rolling_friction"] = rolling_friction
    with World(table_scene(ball)) as w:
        w.step(24)  # settle onto the table
        w.set_velocities(np.array([[-v0, 0, 0, 0, -v0 / 0.03, 0]]), [1])
        speeds = []
        for _ in range(round(seconds / 0.1)):
            w.step(24)
            speeds.append(float(np.linalg.norm(w.get_velocities([1])[0, :2])))
    return np.array(speeds)


def test_a_stated_rolling_friction_is_the_only_rolling_resistance():
    # stated as 0, nothing brakes a rolling ball (no drag from Bullet's angular damping)
    free = _rolling_speeds(0.0)
    assert np.all(np.abs(free - 1.0) < 0.01)
    # stated, it brakes as a constant torque rf * N (table's lateral friction 1): a rolling solid
    # ball decelerates at (5/7) g rf / r whatever its speed (a drag would halve it at half the
    # speed); 15 % for the contact solver
    coulomb = 5 / 7 * 9.81 * 0.002 / 0.03 * 0.1  # m/s lost per 0.1 s
    for v0 in (1.0, 0.5):
        assert -np.diff(_rolling_speeds(0.002, v0=v0)).mean() == pytest.approx(coulomb, rel=0.15)
    # unstated, Bullet's default damping stays: the ball slows, the faster the more
    silent = _rolling_speeds(None)
    assert silent[-1] < 0.9


STACK = table_scene(
    {"id": "a", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.025]}},
    {"id": "b", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.075]}},
    {"id": "c", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0.3, 0, TABLE_TOP + 0.025]}})


def test_bodies_out_of_collision_stay_asleep_in_place_and_collide_again_once_put_back():
    with World(STACK, PhysicsSettings(sleeping=True)) as w:
        w.step(60)
        sleep(w, [1, 2, 3])
        w.step(5)
        rest = w.get_poses([1, 2, 3])
        w.set_colliding([1, 2], False)
        w.step(24)
        assert np.array_equal(w.get_poses([1, 2, 3]), rest)  # asleep: nothing moves them
        assert touching(w, [1]) == [] and touching(w, [3]) == [0]  # a has no contact left; c has
        w.set_colliding([1, 2], True)
        wake(w, [1, 2])
        w.step(60)
        assert touching(w, [1]) == [0, 2]  # on the table again, carrying b
        assert np.allclose(w.get_poses([1, 2])[:, :3], rest[:2, :3], atol=2e-3)
        w.set_colliding([2], False)
        wake(w, [2])  # awake and out of collision: b falls through a and the table
        w.step(60)
        assert w.get_poses([2])[0, 2] < TABLE_TOP - 0.1


def test_set_dynamics_in_one_call_is_the_state_of_one_call_per_kind():
    """A particle's five parameters go to pybullet in one changeDynamics call per object; the world
    then holds what a call for the frictions and restitution followed by one for the mass gives:
    the same dynamics, and the same fall onto the table and roll, bit for bit."""
    import pybullet as pb

    scene = table_scene({"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.2]}},
                        {"id": "box", "box": {"size": [0.05, 0.05, 0.05]},
                         "pose": {"position": [0.1, 0.0, TABLE_TOP + 0.1]}})
    values = dict(lateral_friction=0.37, rolling_friction=0.002, spinning_friction=0.004, restitution=0.3, mass=0.21)
    with World(scene) as one, World(scene) as two:
        for i in (1, 2):
            one.set_dynamics(i, **values)
            pb.changeDynamics(two.uids[i], -1, lateralFriction=0.37, rollingFriction=0.002, spinningFriction=0.004,
                              restitution=0.3, physicsClientId=two.client)
            pb.changeDynamics(two.uids[i], -1, mass=0.21, physicsClientId=two.client)
            assert one.get_dynamics(i) == two.get_dynamics(i)
            assert one.get_dynamics(i)["mass"] == 0.21
        start = one.get_poses()
        v = np.zeros((3, 6))
        v[1, 0] = 0.5  # the ball thrown along x: it lands and rolls
        one.set_velocities(v)
        two.set_velocities(v)
        one.step(240)
        two.step(240)
        assert np.array_equal(one.get_poses(), two.get_poses())
        assert one.get_poses()[1, 0] - start[1, 0] > 0.1  # it moved: the parameters were at work
