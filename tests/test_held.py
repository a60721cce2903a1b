import numpy as np
import pytest

from estimator.worlds.held import HeldObjects, depenetrate, glide_paths
from helpers import TABLE_TOP, table_scene
from physics.transforms import carry_pose, quat_angle, quat_from_rotvec
from physics.world import World

SCENE = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, TABLE_TOP + 0.05]}})


def test_glide_paths_run_straight_along_the_shortest_arc_at_constant_velocity():
    with World(SCENE) as w:
        start = np.array([[0.0, 0.0, 1.0, 0, 0, 0, 1]])
        end = np.concatenate([[[0.19, 0.0, 1.0]], quat_from_rotvec(np.array([[0, 0, 0.5]]))], axis=1)
        com, orn, lin, ang = glide_paths(w, start, end, np.array([1]), 19)
        assert com.shape == (1, 20, 3) and orn.shape == (1, 20, 4)
        assert np.allclose(com[0, 0], start[0, :3]) and np.allclose(com[0, -1], end[0, :3])
        assert np.allclose(np.diff(com[0, :, 0]), 0.01)  # equal steps
        assert quat_angle(orn[0, -1], end[0, 3:]) == pytest.approx(0.0, abs=1e-6)
        dt = 19 * w.settings.time_step
        assert np.allclose(lin[0], [0.19 / dt, 0, 0]) and np.allclose(ang[0], [0, 0, 0.5 / dt])


def test_a_turning_glide_moves_an_offset_centre_of_mass_along_its_chord(tmp_path):
    """pybullet's base velocity is the centre of mass's. An object whose centre of mass is 1 cm off
    its link origin (TURNED_URDF), turned 0.4 rad about z while its link origin moves 5 cm along x:
    the velocity set takes the centre of mass from its start to its end; without the turn it is the
    link origin's exactly (bit for bit), and so it is for a box, whose centre is its origin."""
    (tmp_path / "turned.urdf").write_text(TURNED_URDF)
    scene = table_scene({"id": "turned", "urdf": str(tmp_path / "turned.urdf"), "mass": 0.2,
                         "pose": {"position": [0, 0, TABLE_TOP + 0.2]}})
    start = np.array([[0.0, 0.0, 1.0, 0, 0, 0, 1]])
    turned = np.concatenate([[[0.05, 0.0, 1.0]], quat_from_rotvec(np.array([[0, 0, 0.4]]))], axis=1)
    straight = np.array([[0.05, 0.0, 1.0, 0, 0, 0, 1]])
    n = 10
    with World(scene) as w:
        T = n * w.settings.time_step
        com, _, lin, _ = glide_paths(w, start, turned, np.array([1]), n)
        assert np.allclose(lin[0] * T, com[0, -1] - com[0, 0], atol=1e-12)
        assert np.linalg.norm(lin[0] - [0.05 / T, 0, 0]) * T > 1e-3  # the arc of a 1 cm lever through 0.4 rad
        _, _, lin, _ = glide_paths(w, start, straight, np.array([1]), n)
        assert np.array_equal(lin[0], (straight[0, :3] - start[0, :3]) / T)
    with World(SCENE) as w:
        _, _, lin, _ = glide_paths(w, start, turned, np.array([1]), n)
        assert np.array_equal(lin[0], (turned[0, :3] - start[0, :3]) / T)


def test_depenetrate_pushes_a_sunk_box_out_of_the_table():
    with World(SCENE) as w:
        w.set_poses([[0.0, 0.0, TABLE_TOP + 0.03, 0, 0, 0, 1]], [1])  # 2 cm into the table top
        depenetrate(w, [1])
        assert w.get_poses([1])[0, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)


def test_depenetrate_keeps_a_rolling_objects_velocity():
    """pybullet's reset of a pose zeroes the velocity: a can rolling on the floor, nudged out of it
    at every update, would stop short of where it rolls to."""
    with World(SCENE) as w:
        w.set_poses([[0.0, 0.0, TABLE_TOP + 0.04, 0, 0, 0, 1]], [1])
        v = np.array([[0.4, -0.1, 0.0, 0.0, 0.0, 1.5]])
        w.set_velocities(v, [1])
        depenetrate(w, [1])
        assert w.get_poses([1])[0, 2] > TABLE_TOP + 0.045  # it was pushed out
        assert np.allclose(w.get_velocities([1]), v, atol=1e-9)


def test_hand_offset_walk_variance_follows_the_ornstein_uhlenbeck_law():
    """From zero, after t seconds in steps of dt, the error's variance per axis is
    std^2 (1 - exp(-2 t / tau)); checked on 3 x 4000 draws against the chi-square band (99.9 %)."""
    from scipy.stats import chi2

    from estimator.worlds.held import hand_offset_walk

    rng = np.random.default_rng(11)
    std, tau, dt = 0.02, 0.5, 0.08
    err = np.zeros((4000, 3))
    for n in range(1, 16):
        err = hand_offset_walk(err, dt, std, tau, rng)
        if n in (3, 15):
            var = std ** 2 * (1 - np.exp(-2 * n * dt / tau))
            dof = err.size
            stat = np.sum(err ** 2) / var
            assert chi2.ppf(0.0005, dof) < stat < chi2.ppf(0.9995, dof), n
    assert np.all(hand_offset_walk(err, dt, 0.0, tau, rng) == 0)


@pytest.mark.parametrize("moving", [False, True])
@pytest.mark.parametrize("turning", [False, True])
def test_a_jump_lands_at_the_target_with_its_contents_carried_rigidly(moving, turning):
    """An object that becomes held jumps to its target (plain floats, from the caller's
    centre-of-mass targets) with its contents carried rigidly: its link frame and velocity, and its
    content's, are those of the rigid carry computed with arrays on link frames
    (:func:`physics.transforms.carry_pose`), for a box turned by its jump, moving or not, turning
    or not, with a teddy on it (the teddy's centre of mass off its link origin, the teddy turning)."""
    scene = table_scene({"id": "box", "box": {"size": [0.2, 0.2, 0.04]},
                         "pose": {"position": [0, 0, TABLE_TOP + 0.02], "orientation": [0, 0, 0.2, 0.9797959]}},
                        {"id": "teddy", "urdf": "pybullet_data://teddy_vhacd.urdf", "mass": 0.1,
                         "pose": {"position": [0.05, 0, TABLE_TOP + 0.07]}})
    n, s = 20, 7
    target = np.zeros((3, 7))
    target[:, 6] = 1.0
    target[1] = [0.1, -0.05, TABLE_TOP + 0.12, *quat_from_rotvec(np.array([0.1, -0.2, 0.6]))]
    tvel = np.zeros((3, 6))
    tvel[1] = [0.3, -0.1, 0.2, *([0.3, 0.0, -0.5] if turning else [0.0] * 3)]
    contents = np.zeros((3, 3), dtype=bool)
    contents[2, 1] = True  # the teddy is on the box
    with World(scene) as w:
        spin = np.array([[0.05, 0.0, -0.1, 0.5, -1.0, 2.0]])
        w.set_velocities(spin, [2])  # the teddy turns
        dt = w.settings.time_step
        box_at = target[1].copy()  # where the target is before step s + 1
        if moving:
            box_at[:3] += (s - n) * dt * tvel[1, :3]
        teddy_at = carry_pose(w.get_poses([2])[0], w.get_poses([1])[0], box_at)
        com = w.com_frame(target[None])[0][0]
        start = com[:, :3] + w.origin - (tvel[:, :3] * (n * dt) if moving else 0.0)
        h = HeldObjects(w, start.tolist(), com[:, 3:], tvel, contents, n, moving)
        h.jump([1], s)
        assert np.allclose(w.get_poses([1, 2]), [box_at, teddy_at], atol=1e-12)
        assert np.allclose(w.get_velocities([1, 2]), [tvel[1], [*tvel[1, :3], *spin[0, 3:]]], atol=1e-12)
        h.apply(n + 1)
        end = w.get_poses([1])[0]
    assert np.allclose(end, target[1], atol=1e-9) or np.allclose(end[3:], -target[1, 3:], atol=1e-9)


TURNED_URDF = """<?xml version="1.0"?>
<robot name="turned"><link name="base">
  <inertial><origin xyz="0.01 0 0" rpy="0 0 0.7"/><mass value="0.2"/>
    <inertia ixx="1e-4" iyy="2e-4" izz="3e-4" ixy="0" ixz="0" iyz="0"/></inertial>
  <collision><geometry><box size="0.06 0.04 0.02"/></geometry></collision>
</link></robot>
"""


def test_held_objects_end_at_their_target_when_their_inertial_frame_is_turned(tmp_path):
    """pybullet sets a body by its centre-of-mass frame, which a URDF may turn from the link frame
    (here 0.7 rad about z): held by a glide, by a jump, or by a jump out of its parking, the object
    ends with its link frame at the target, not turned by that rotation."""
    (tmp_path / "turned.urdf").write_text(TURNED_URDF)
    scene = table_scene({"id": "turned", "urdf": str(tmp_path / "turned.urdf"), "mass": 0.2,
                         "pose": {"position": [0, 0, TABLE_TOP + 0.2]}})
    target = np.zeros((2, 7))
    target[:, 6] = 1.0
    target[1] = [0.1, 0.05, TABLE_TOP + 0.3, *quat_from_rotvec(np.array([0.2, 0.0, 0.4]))]
    n = 12
    for how in ("glide", "jump", "jump from its parking"):
        with World(scene) as w:
            com = w.com_frame(target[None])[0][0]
            assert quat_angle(com[1, 3:], target[1, 3:]) > 0.6  # the frames differ
            if how == "jump from its parking":
                w.set_poses(w.parked_pose[[1]], [1])
                assert w.is_parked(1)
            h = HeldObjects(w, (com[:, :3] + w.origin).tolist(), com[:, 3:], np.zeros((2, 6)), np.zeros((2, 2), bool), n)
            if how == "glide":
                p, q, lin, ang = glide_paths(w, w.get_poses([1]), target[1:], np.array([1]), n)
                h.glide(w.uids[1], (p[0] + w.origin).tolist(), q[0].tolist(), lin[0].tolist(), ang[0].tolist())
            else:
                h.jump([1], 3)
            h.apply(n + 1)
            got = w.get_poses([1])[0]
            assert not w.is_parked(1)
            assert np.allclose(got[:3], target[1, :3], atol=1e-9), how
            assert quat_angle(got[3:], target[1, 3:]) < 1e-6, how
