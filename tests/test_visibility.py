import math

import numpy as np
import pytest

from helpers import TABLE_TOP, table_scene
from physics import sightlines, visibility
from physics.group import WorldGroup
from physics.scene import CameraSpec
from physics.visibility import (
    Camera,
    first_copies,
    local_box,
    local_sample_points,
    rays_clear_of,
    solid_box,
    sphere_occlusion,
    visible_enough,
    visible_fraction,
    visible_fractions,
)
from physics.world import World

CAM = {"position": [1.5, 0.0, 1.0], "target": [0.0, 0.0, 0.7], "fov_deg": 60, "far": 4.0}


def test_frustum():
    cam = Camera(CameraSpec(position=(0, 0, 0), target=(1, 0, 0), fov_deg=90, aspect=1.0, near=0.1, far=5))
    pts = np.array([[1, 0, 0], [1, 0.9, 0], [1, 1.1, 0], [0.05, 0, 0], [6, 0, 0], [-1, 0, 0]])
    assert cam.in_view(pts).tolist() == [True, True, False, False, False, False]


def test_occlusion_by_a_box_and_by_container_walls():
    scene = table_scene(
        {"id": "wall", "box": {"size": [0.05, 0.4, 0.3]}, "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.15]}},
        {"id": "hidden", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.025]}},
        {"id": "open", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0.0, 0.35, TABLE_TOP + 0.025]}},
        camera=CAM)
    with World(scene) as w:
        cam = Camera(scene.camera)
        pts = {i: local_sample_points(w, i) for i in range(w.num_objects)}
        frac = visible_fraction(w, cam, [1, 2, 3], pts)
    assert frac[0] > 0.8 and frac[1] < 0.05 and frac[2] > 0.8


def test_rays_clear_of_bodies_away_from_the_line_of_sight():
    cam = Camera(CameraSpec(position=(0, 0, 0), target=(1, 0, 0)))
    centres = np.array([[2.0, 0, 0], [2.0, 1.0, 0]])
    radii = np.array([0.1, 0.1])
    # a body on the first line of sight, one on the second, one 0.5 m beside the first (0.89 m from
    # the second), one behind the camera, one beyond the objects
    others = np.array([[1.0, 0.05, 0], [1.0, 0.5, 0], [1.0, -0.5, 0], [-0.5, 0, 0], [3.0, 0, 0]])
    other_radii = np.full(5, 0.1)
    clear = [rays_clear_of(cam, centres, radii, others[[j]], other_radii[[j]]).tolist() for j in range(5)]
    assert clear == [[False, True], [True, False], [True, True], [True, True], [True, True]]
    assert rays_clear_of(cam, centres, radii, others[[2]], np.array([0.45])).tolist() == [False, True]
    assert rays_clear_of(cam, centres, radii, others, other_radii).tolist() == [False, False]
    assert rays_clear_of(cam, centres, radii, np.zeros((0, 3)), np.zeros(0)).all()


def test_visible_fractions_of_copies_in_one_client_match_each_world_alone():
    scene = table_scene(
        {"id": "wall", "box": {"size": [0.05, 0.4, 0.3]}, "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.15]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.03]}},
        camera=CAM)
    cam = Camera(scene.camera)
    with WorldGroup(scene, copies=3) as g, World(scene) as alone:
        pts = {i: local_sample_points(alone, i, 2) for i in range(alone.num_objects)}
        assert np.allclose(local_box(alone, 2)[1], 0.03, atol=2e-3)  # a sphere's box: its radius, plus margin
        g.worlds[1].set_poses([[0.0, 0.3, TABLE_TOP + 0.03, 0, 0, 0, 1]], [2])  # out from behind the wall
        poses = np.stack([w.get_poses([2]) for w in g.worlds])
        frac = visible_fractions(g.worlds, cam, [2], pts, poses)
        need = np.array([[True], [False], [True]])
        partial = visible_fractions(g.worlds, cam, [2], pts, poses, need)
        for k in range(3):
            alone.set_poses(poses[k], [2])
            assert frac[k, 0] == visible_fraction(alone, cam, [2], pts)[0]
        assert frac[0, 0] < 0.05 and frac[1, 0] > 0.8 and frac[2, 0] < 0.05
        assert partial[1, 0] == 0.0 and partial[0, 0] == frac[0, 0]


def test_first_copies_point_each_particle_to_the_first_equal_one():
    poses = np.zeros((6, 2, 7))
    poses[:, :, 0] = [[0, 1], [2, 3], [0, 1], [2, 3], [0, 1.5], [0, 1]]
    assert first_copies(poses).tolist() == [0, 1, 0, 1, 4, 0]
    poses[5, 1, 6] = -0.0  # bit for bit (a copy is what resampling makes): -0.0 is not 0.0
    assert first_copies(poses).tolist() == [0, 1, 0, 1, 4, 5]


def test_solid_box_is_the_collision_box_of_boxes_only():
    turned = [0, 0, 0.38268343, 0.92387953]  # 45 degrees about z
    scene = table_scene({"id": "block", "box": {"size": [0.2, 0.1, 0.04]},
                         "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.02], "orientation": turned}},
                        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.03]}},
                        {"id": "bin", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01},
                         "pose": {"position": [-0.3, 0.0, TABLE_TOP + 0.06]}},
                        {"id": "plate", "box": {"size": [0.2, 0.2, 0.008]},
                         "pose": {"position": [0.0, 0.3, TABLE_TOP + 0.004]}})
    with World(scene) as w:
        table = solid_box(w, 0)  # pybullet_data's table: one box, 1.5 x 1 x 0.05 m, 0.6 m above its origin
        assert np.allclose(table[0], [0, 0, 0.6], atol=1e-9) and np.allclose(table[1], [0.745, 0.495, 0.02])
        block = solid_box(w, 1)  # turned in the scene, a box in its own frame
        assert np.allclose(block[0], 0, atol=1e-9) and np.allclose(block[1], [0.095, 0.045, 0.015])
        assert solid_box(w, 2) is None and solid_box(w, 3) is None  # a sphere, a container of five boxes
        assert solid_box(w, 4) is None  # thinner than twice SOLID_DEPTH


def test_visible_enough_is_the_fraction_against_the_threshold_with_fewer_rays(monkeypatch):
    scene = table_scene(
        {"id": "wall", "box": {"size": [0.05, 0.4, 0.3]}, "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.15]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.03]}},
        camera=CAM)
    cams = [Camera(scene.camera), Camera(CameraSpec(position=(0.2, 1.2, 1.0), target=(0.0, 0.0, TABLE_TOP))),
            Camera(CameraSpec(position=(0.9, 0.25, 0.75), target=(0.0, 0.12, TABLE_TOP)))]
    with WorldGroup(scene, copies=6) as g:
        pts = {i: local_sample_points(g.worlds[0], i, 2) for i in range(3)}
        for k, y in enumerate([0.0, 0.1, 0.17, 0.2, 0.23, 0.35]):  # behind the wall, at its edge, beside it
            g.worlds[k].set_poses([[0.0, y, TABLE_TOP + 0.03, 0, 0, 0, 1]], [2])
        poses = np.stack([w.get_poses([2]) for w in g.worlds])
        frac = np.array([visible_fractions(g.worlds, c, [2], pts, poses) for c in cams])
        assert 0 < np.mean(frac > 0) < 1 and np.any((frac > 0) & (frac < 1))  # seen, hidden and partly hidden
        cast = []
        monkeypatch.setattr(visibility, "LAST_ROUND_RAYS", 0)  # rounds to the end, however few rays are left
        real = sightlines.ray_cast
        monkeypatch.setattr(sightlines, "ray_cast", lambda c, s, e: cast.append(len(s)) or real(c, s, e))
        for thr in (0.0, 2 / 9, 0.3, 0.5, 1.0, 1.5):
            cast.clear()
            assert np.array_equal(visible_enough(g.worlds, cams, [2], pts, poses, thr), frac >= thr)
            assert sum(cast) <= 9 * frac.size
            if thr == 0.3:
                assert sum(cast) < 0.8 * 9 * frac.size  # decided before every point is tested


def test_a_hand_sphere_hides_the_part_of_a_disk_it_covers_from_in_front():
    """The hand as a sphere (sphere_occlusion): a ball straight behind a larger hand is hidden, one in
    front of it or far to the side is not, and two disks of the same apparent radius a whose centres
    are a apart overlap by (2 pi / 3 - sqrt(3) / 2) / pi of a disk (small angles)."""
    eye = np.zeros(3)
    hand = np.array([[1.0, 0.0, 0.0]])
    centres = np.array([[2.0, 0.0, 0.0], [0.5, 0.0, 0.0], [2.0, 1.0, 0.0]])
    share = sphere_occlusion(eye, centres, np.array([0.04, 0.02, 0.04]), hand, 0.045)
    assert share[0] == pytest.approx(1.0) and share[1] == 0.0 and share[2] == 0.0
    a = 0.01  # the hand at 1 m and the object at 2 m, both of apparent radius a, a apart
    centre = 2.0 * np.array([[math.cos(a), math.sin(a), 0.0]])
    lens = (2 * math.pi / 3 - math.sqrt(3) / 2) / math.pi
    assert sphere_occlusion(eye, centre, np.array([2 * math.sin(a)]), hand, math.sin(a))[0] == pytest.approx(lens, rel=1e-3)
    assert sphere_occlusion(eye, centres, np.array([0.04, 0.02, 0.04]), np.zeros((0, 3)), 0.045).sum() == 0.0


def test_the_batched_ray_clearance_equals_one_world_at_a_time():
    from physics.scene import CameraSpec
    rng = np.random.default_rng(12)
    cam = Camera(CameraSpec(position=(1.2, 0.0, 1.3), target=(0.0, 0.0, 0.6)))
    G, n, m = 40, 3, 7
    centres = rng.uniform(-0.4, 0.4, (G, n, 3)) + [0, 0, 0.7]
    bodies = rng.uniform(-0.4, 0.6, (G, m, 3)) + [0, 0, 0.7]
    radii, body_radii = rng.uniform(0.02, 0.08, n), rng.uniform(0.02, 0.1, m)
    moved = rng.uniform(size=(G, m)) < 0.4
    got = rays_clear_of(cam, centres, radii, bodies, body_radii, moved)
    want = np.array([rays_clear_of(cam, centres[g], radii, bodies[g][moved[g]], body_radii[moved[g]])
                     for g in range(G)])
    assert np.array_equal(got, want) and 0 < got.sum() < got.size
