"""physics.rays: batched ray tests, split into batches pybullet accepts."""
import numpy as np

from helpers import TABLE_TOP, table_scene
from physics import rays
from physics.world import World


def test_rays_hit_what_is_under_them_and_a_long_batch_is_split_without_changing_the_answers(monkeypatch):
    box = {"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, TABLE_TOP + 0.05]}}
    with World(table_scene(box)) as w:
        xs = np.linspace(-0.3, 0.3, 61)
        starts = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 2.0)], axis=1)
        ends = starts * [1, 1, 0] + [0, 0, TABLE_TOP + 0.07]  # stops above the table, inside the box
        uids, frac = rays.ray_cast(w.client, starts, ends)
        inside = np.abs(xs) < 0.05 - 1e-9
        assert np.all(uids[inside] == w.uids[1]) and np.all(uids[~inside & (np.abs(xs) > 0.05 + 1e-9)] == -1)
        expected = (2.0 - (TABLE_TOP + 0.1)) / (2.0 - (TABLE_TOP + 0.07))
        assert np.allclose(frac[inside], expected, atol=1e-4) and np.all(frac[uids == -1] == 1.0)
        monkeypatch.setattr(rays, "MAX_RAYS_PER_BATCH", 7)  # nine batches, the same answers
        again = rays.ray_cast(w.client, starts, ends)
        assert np.array_equal(again[0], uids) and np.array_equal(again[1], frac)
