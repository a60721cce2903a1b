"""Penetration depths into static geometry, and paths stopped at its surface (physics/penetration.py)."""
import numpy as np
import pytest

from helpers import table_scene
from physics.penetration import INVARIANT_DEPTH, StaticGeometry

TABLE_TOP = 0.625  # the top of the table's collision box (helpers.TABLE_TOP is where objects rest on it)

BALL = {"id": "ball", "sphere": {"radius": 0.03}}
BOX = {"id": "box", "box": {"size": [0.1, 0.06, 0.04]}}
DUCK = {"id": "duck", "urdf": "pybullet_data://duck_vhacd.urdf"}


def poses(*rows):
    out = np.zeros((len(rows), 7))
    out[:, 6] = 1.0
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


@pytest.fixture(scope="module")
def geometry():
    with StaticGeometry(table_scene(BALL, BOX, DUCK)) as g:
        yield g


def test_depths_are_how_far_an_object_is_inside_the_table_or_under_the_floor(geometry):
    # the ball resting on the table, 2 and 5 cm into its top, and 4 cm under the floor beside it
    ball = poses([0, 0, TABLE_TOP + 0.03], [0, 0, TABLE_TOP + 0.01], [0, 0, TABLE_TOP - 0.02], [2.0, 0, -0.01])
    d = geometry.depth_of(1, ball)
    assert d[0] < 1e-3
    assert d[1:] == pytest.approx([0.02, 0.05, 0.04], abs=1e-3)
    # a box turned on its side: its half height is then 5 cm, not 2
    q = [0, np.sin(np.pi / 4), 0, np.cos(np.pi / 4)]
    assert geometry.depth_of(2, poses([0.3, 0, TABLE_TOP + 0.045, *q]))[0] == pytest.approx(0.005, abs=1e-3)


def test_depths_of_a_stack_skip_static_parked_and_non_finite_entries(geometry):
    stack = np.zeros((2, 4, 7))
    stack[..., 6] = 1.0
    stack[:, 0, :3] = [0, 0, 0]  # the table itself: never measured
    stack[0, 1, :3] = [0, 0, TABLE_TOP - 0.01]  # 4 cm in
    stack[1, 1, :3] = [50, 50, -50]  # parked: not known yet
    stack[0, 2, :3] = np.nan
    stack[1, 2, :3] = [0.2, 0.2, TABLE_TOP + 0.02]
    stack[:, 3, :3] = [-0.3, 0.0, 1.0]
    d = geometry.depths(stack)
    assert d.shape == (2, 4)
    assert d[0, 1] == pytest.approx(0.04, abs=1e-3)
    assert d[0, 0] == d[1, 1] == d[0, 2] == 0.0
    assert np.array_equal(geometry.violations(stack), d > INVARIANT_DEPTH)
    with pytest.raises(ValueError):
        geometry.depths(stack[:, :3])


def test_a_path_into_the_table_stops_at_its_surface_and_one_through_its_top_too(geometry):
    start = poses([0, 0, 0.9], [0, 0, 0.9], [0.1, 0, TABLE_TOP + 0.031], [0, 0, 1.0])
    # straight down to the floor (the end is clear: the top is 5 cm thick, the path crosses it),
    # down to 1 cm above the top (kept), along the top sinking 2 cm (stopped), and up (kept)
    end = poses([0, 0, 0.3], [0, 0, TABLE_TOP + 0.04], [0.5, 0, TABLE_TOP + 0.01], [0, 0, 1.2])
    new, frac = geometry.clip(1, start, end)
    top = TABLE_TOP + 0.03  # the ball's centre when it rests on the table
    assert new[0, 2] == pytest.approx(top, abs=0.005) and 0 < frac[0] < 1
    assert np.array_equal(new[[1, 3]], end[[1, 3]]) and np.all(frac[[1, 3]] == 1.0)
    assert 0 < frac[2] < 1 and geometry.depth_of(1, new[2:3])[0] <= 0.004 + 1e-4
    assert new[2, 2] >= top - 0.005


def test_a_path_that_starts_inside_ends_pushed_out(geometry):
    start = poses([0.2, 0, TABLE_TOP - 0.01])
    end = poses([0.25, 0, TABLE_TOP - 0.005])
    new, frac = geometry.clip(1, start, end)
    assert np.isnan(frac[0])
    assert geometry.depth_of(1, new)[0] < 1e-3


def test_a_mesh_object_is_stopped_too(geometry):
    start = poses([-0.3, 0.1, 0.9])
    end = poses([-0.3, 0.1, 0.4])
    new, frac = geometry.clip(3, start, end)
    assert 0 < frac[0] < 1
    assert geometry.depth_of(3, new)[0] <= 0.004 + 1e-4
    assert new[0, 2] > TABLE_TOP - 0.01


def test_the_box_prefilter_keeps_every_object_that_is_deep_inside(geometry):
    # random poses of the ball, the box and the duck around the table top and the floor: every one
    # more than INVARIANT_DEPTH deep must pass the prefilter (it may pass more: boxes are loose)
    rng = np.random.default_rng(7)
    w = geometry.world
    n = 200
    for m in (1, 2, 3):
        p = np.zeros((n, 7))
        p[:, 0] = rng.uniform(-0.9, 0.9, n)
        p[:, 1] = rng.uniform(-0.6, 0.6, n)
        p[:, 2] = rng.choice([TABLE_TOP, 0.0], n) + rng.uniform(-0.08, 0.08, n)
        q = rng.normal(size=(n, 4))
        p[:, 3:] = q / np.linalg.norm(q, axis=1, keepdims=True)
        boxes = np.empty((n, 2, 3))
        for i in range(n):
            w.set_poses(p[i:i + 1], [m])
            boxes[i] = w.aabbs([m])[0]
        w.set_poses(w.parked_pose[[m]], [m])
        deep = geometry.depth_of(m, p) > INVARIANT_DEPTH
        kept = geometry.may_be_inside(boxes)
        assert deep.sum() > 10 and not np.any(deep & ~kept)
        assert kept.sum() < n  # and it does leave some out
    assert geometry.may_be_inside(np.zeros((2, 3, 2, 3)) + [[0, 0, 5.0], [0.1, 0.1, 5.1]]).shape == (2, 3)



def test_one_pose_clear_of_static_is_the_box_test_in_plain_floats(geometry):
    """``clear_of_static`` (one pose, plain floats) answers as the box test of ``depth_of`` (numpy,
    any number of poses) on random poses of a sphere, a box and a mesh near the table top and the
    floor, at three margins; where it says clear, the depth is under the margin. A non-finite pose
    or a zero quaternion is never clear."""
    rng = np.random.default_rng(11)
    n, agree, clear = 300, 0, 0
    for m in (1, 2, 3):
        p = np.zeros((n, 7))
        p[:, :2] = rng.uniform([-0.9, -0.6], [0.9, 0.6], (n, 2))
        p[:, 2] = rng.choice([TABLE_TOP, 0.0], n) + rng.uniform(-0.1, 0.1, n)
        p[:, 3:] = rng.normal(size=(n, 4))  # not normalised: the test normalises, as depth_of does
        for margin in (0.0, 0.004, INVARIANT_DEPTH):
            boxed = geometry._candidates(m, p, margin).any(axis=1)
            fast = np.array([geometry.clear_of_static(m, row.tolist(), margin) for row in p])
            agree += int(np.sum(fast == ~boxed))
            clear += int(fast.sum())
            assert np.all(geometry.depth_of(m, p[fast], margin) <= margin)
    assert agree == 3 * 3 * n and 0 < clear < 3 * 3 * n
    assert not geometry.clear_of_static(2, [0.3, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0], 0.0)  # zero quaternion
    assert not geometry.clear_of_static(2, [np.nan, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0], 0.0)
    assert geometry.clear_of_static(2, [0.3, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0], 0.0)  # 87 cm above the top


def test_a_depth_asked_again_is_remembered_not_measured_again(monkeypatch):
    """depth_of keeps the answers of its last call per object and margin (static geometry never
    moves): the same poses asked again make no pybullet query and get the same depths; other poses
    asked in between replace what is kept (one call's poses, however long the run); asked with
    another margin (other static bodies in the box test) they are measured as by a new geometry."""
    import pybullet as pb
    calls = []
    closest = pb.getClosestPoints
    monkeypatch.setattr(pb, "getClosestPoints", lambda *a, **k: calls.append(a) or closest(*a, **k))
    rng = np.random.default_rng(5)
    ducks = poses(*[[x, y, TABLE_TOP + z] for x, y, z in rng.uniform([-0.3, -0.3, -0.03], [0.3, 0.3, 0.02], (20, 3))])
    with StaticGeometry(table_scene(BALL, BOX, DUCK)) as g, StaticGeometry(table_scene(BALL, BOX, DUCK)) as fresh:
        first = g.depth_of(3, ducks)
        n = len(calls)
        assert n > 0 and np.any(first > 0)
        assert np.array_equal(g.depth_of(3, ducks[::-1]), first[::-1]) and len(calls) == n
        for beyond in (0.0, INVARIANT_DEPTH):  # another margin: what a geometry that never saw them says
            assert np.array_equal(g.depth_of(3, ducks, beyond), fresh.depth_of(3, ducks, beyond))
        n = len(calls)
        for k in range(1, 4):  # other poses: what is kept is the last call's, no more
            g.depth_of(3, ducks + [0.001 * k, 0, 0, 0, 0, 0, 0])
            assert len(g._depths[(3, 0.0)]) <= len(ducks)
        assert len(calls) > n
        n = len(calls)
        assert np.array_equal(g.depth_of(3, ducks), first) and len(calls) > n
        # one pose asked for every row (a detection all particles share): measured once
        deep = int(np.argmax(first))
        n = len(calls)
        once = fresh.depth_of(3, ducks[deep:deep + 1] + [0.002, 0, 0, 0, 0, 0, 0])
        one_query = len(calls) - n
        n = len(calls)
        shared = np.repeat(ducks[deep:deep + 1] + [0.002, 0, 0, 0, 0, 0, 0], 30, axis=0)
        assert np.array_equal(g.depth_of(3, shared), np.full(30, once[0])) and len(calls) - n == one_query


def test_what_holds_an_object_up_moves_with_it_along_a_flat_top_only(geometry):
    """The box resting on the table URDF's top (1.5 m x 1 m): the rays under its box's centre and
    corners all meet the table at its top with the normal up, slid 5 cm along the top as well.
    Half over the table's edge (x = 0.75 m, the box's centre 1 cm in), two corners find nothing
    within reach. The table's box reaches a millimetre above its top; the only static body near
    the box is the table, and none near it high in the air."""
    rest = TABLE_TOP + 0.02
    at = poses([0.2, 0.1, rest], [0.25, 0.1, rest], [0.74, 0.1, rest], [0.2, 0.1, rest + 0.5])
    under = geometry.under(2, at, 0.02)
    assert under.shape == (4, 5, 5)
    table = geometry.static_uids.index(geometry.world.uids[0])
    assert np.all(under[:2, :, 0] == table)
    assert np.allclose(under[:2, :, 1], TABLE_TOP, atol=1e-6) and np.allclose(under[:2, :, 2:], [0, 0, 1], atol=1e-9)
    assert np.all(under[2, [0, 1, 2], 0] == table) and np.all(under[2, [3, 4], 0] == -1)  # the corners past x = 0.75
    assert np.all(np.isnan(under[2, [3, 4], 1:])) and np.all(under[3, :, 0] == -1)
    assert 0.0 <= geometry.static_top([table])[0] - TABLE_TOP <= 0.002
    near = geometry.near_static(2, at, 0.02)
    assert near.shape == (4, len(geometry.static_uids))
    assert np.all(near[:3, table]) and near[:3].sum() == 3 and not near[3].any()
    lo, hi = geometry.box(2, at[:1])
    assert np.allclose(lo, [[0.15, 0.07, TABLE_TOP]]) and np.allclose(hi, [[0.25, 0.13, TABLE_TOP + 0.04]])
