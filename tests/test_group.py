import numpy as np
import pytest

from helpers import TABLE_TOP, table_scene
from physics.group import SPACING, WorldGroup
from physics.world import PhysicsSettings, World

SCENE = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [0, 0, TABLE_TOP + 0.3]}},
                    {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.2, 0, TABLE_TOP + 0.5]}},
                    {"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}})  # no pose: parked


def test_copies_sit_apart_and_answer_in_their_own_scene_frame():
    with WorldGroup(SCENE, copies=5) as g:
        origins = g.origins
        assert len({tuple(o) for o in origins}) == 5
        d = np.linalg.norm(origins[:, None] - origins[None], axis=-1)
        assert d[~np.eye(5, dtype=bool)].min() >= SPACING
        for w in g.worlds:
            assert w.client == g.client
            assert np.allclose(w.get_poses([1])[0, :3], [0, 0, TABLE_TOP + 0.3])
            lo, hi = w.aabbs([1])[0]
            assert np.allclose((lo + hi) / 2, [0, 0, TABLE_TOP + 0.3], atol=1e-3)
            hit, frac = w.ray_test([[0, 0, 2.0]], [[0, 0, 0]])  # straight down onto the box
            assert hit[0] == 1 and frac[0] == pytest.approx((2.0 - TABLE_TOP - 0.35) / 2.0, abs=2e-3)


def test_a_copy_moves_as_a_world_alone_and_ignores_its_neighbours():
    with WorldGroup(SCENE, copies=3) as g, WorldGroup(SCENE, copies=3) as quiet, World(SCENE) as alone:
        g.worlds[2].set_poses([[0.0, 0.0, TABLE_TOP + 1.0, 0, 0, 0, 1]], [1])  # only copy 2 differs
        for x in (g, quiet, alone):
            x.step(120)
        a, b, c = (w.get_poses() for w in g.worlds)
        # a copy's result does not depend on what the other copies do, bit for bit
        assert all(np.array_equal(w.get_poses(), v.get_poses()) for w, v in zip(g.worlds[:2], quiet.worlds))
        assert np.allclose(a, b, atol=1e-9)  # copies differ only by round-off (their origins differ)
        assert not np.allclose(a[1], c[1])
        assert np.allclose(a[:3], alone.get_poses()[:3], atol=1e-6)  # the box and ball fell as alone
        assert a[1, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)


def test_parked_objects_stay_parked_until_given_a_pose():
    with WorldGroup(SCENE, copies=2) as g:
        w = g.worlds[0]
        parked = w.get_poses([3])[0]
        assert np.allclose(parked, w.parked_pose[3])
        g.step(240)  # a second: a parked object under the floor plane neither falls nor is pushed up
        assert np.allclose(w.get_poses([3])[0], parked)
        assert np.allclose(g.worlds[1].get_poses([3])[0], g.worlds[1].parked_pose[3])
        w.set_poses([[0.3, -0.2, TABLE_TOP + 0.2, 0, 0, 0, 1]], [3])
        g.step(240)
        assert w.get_poses([3])[0, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)  # now it lands on the table
        w.set_poses(w.parked_pose[[3]], [3])  # parked again
        g.step(24)
        assert np.allclose(w.get_poses([3])[0], w.parked_pose[3])


def test_saved_state_covers_every_copy():
    with WorldGroup(SCENE, PhysicsSettings(), copies=2) as g:
        sid = g.save_state()
        before = [w.get_poses() for w in g.worlds]
        g.step(60)
        g.restore_state(sid)
        g.remove_state(sid)
        assert all(np.array_equal(b, w.get_poses()) for b, w in zip(before, g.worlds))


def test_a_group_needs_a_copy():
    with pytest.raises(ValueError, match="at least one copy"):
        WorldGroup(SCENE, copies=0)


def test_copies_added_later_take_the_places_they_would_have_had_built_at_once():
    with WorldGroup(SCENE, copies=7) as whole, WorldGroup(SCENE, copies=2, capacity=7) as grown:
        assert len(grown.worlds) == 2
        added = grown.grow(5)
        assert len(added) == 3 and len(grown.worlds) == 5 and grown.grow(5) == []
        grown.grow(7)
        assert np.array_equal(grown.origins, whole.origins)
        for w in grown.worlds:
            assert np.allclose(w.get_poses([1])[0, :3], [0, 0, TABLE_TOP + 0.3])
        with pytest.raises(ValueError):
            grown.grow(8)
    with pytest.raises(ValueError):
        WorldGroup(SCENE, copies=3, capacity=2)
