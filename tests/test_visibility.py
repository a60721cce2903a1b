import numpy as np

from physics.scene import CameraSpec
from physics.visibility import Camera, local_sample_points, visible_fraction
from physics.world import World

from helpers import TABLE_TOP, table_scene

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
