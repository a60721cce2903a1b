import numpy as np
import pytest

from estimator.worlds.batch import PER_PARTICLE, BatchInput, ParticleWorld, StepInput
from estimator.worlds.frozen import FREEZE_MARGIN, alone, local_boxes, unreachable
from estimator.worlds.propagate import propagate, propagate_batch
from helpers import TABLE_TOP, table_scene
from physics.world import PhysicsSettings, World

T = 0.08  # s: the update's length in the array tests
FALL = 0.5 * 9.81 * T ** 2 + FREEZE_MARGIN


def _line(xs, halves, speed):
    """One particle: a static table (0), a ball at x = 0 moving at ``speed`` m/s along x (1), and
    boxes at rest at ``xs`` (2...) of half-size ``halves``; all at z = 0, axis-aligned."""
    M = 2 + len(xs)
    poses = np.zeros((1, M, 7))
    poses[..., 6] = 1.0
    poses[0, 2:, 0] = xs
    shift = np.zeros((1, M, 3))
    shift[0, 1, 0] = speed * T  # where its velocity takes the ball
    half = np.zeros((M, 3))
    half[1] = 0.03
    half[2:] = halves
    resting = np.zeros((1, M), bool)
    resting[0, 2:] = True
    awake = np.zeros((1, M), bool)
    awake[0, 1] = True
    speeds = np.zeros((1, M))
    speeds[0, 1] = speed
    return poses, shift, poses.copy(), np.zeros((1, M)), speeds, (np.zeros((M, 3)), half), resting, awake


def test_what_the_ball_may_hit_and_what_that_may_hit_are_not_frozen_the_rest_is():
    reach = 4 * 1.0 * T + FALL  # how far a box the ball hits may move
    ball_hi = 1.0 * T + 0.03  # the ball's box where its velocity takes it
    # box 2 in the ball's way; box 3 beyond the ball's sweep but within a hit box 2's reach; box 4 beyond both
    x2 = ball_hi + FALL + 0.05 - 0.005
    x3 = x2 + 0.05 + reach + 0.05 - 0.005
    x4 = x3 + 0.05 + reach + 0.05 + 0.005
    assert x3 - 0.05 > ball_hi + FALL  # box 3 is out of the ball's own reach
    frozen = unreachable(*_line([x2, x3, x4], 0.05, 1.0), horizon=T)
    assert frozen[0].tolist() == [False, False, False, False, True]
    # a slower ball: a box in its way is reached, but what that box may then hit is nearer
    x2s = 0.1 * T + 0.03 + FALL + 0.05 - 0.005
    assert x3 - 0.05 > x2s + 0.05 + 4 * 0.1 * T + FALL
    slow = unreachable(*_line([x2s, x3], 0.05, 0.1), horizon=T)
    assert slow[0].tolist() == [False, False, False, True]
    # nothing awake: everything at rest is frozen; what is not resting never is
    poses, shift, targets, spread, speeds, boxes, resting, awake = _line([x2, x3, x4], 0.05, 1.0)
    assert unreachable(poses, shift, targets, spread, speeds, boxes, resting, awake & False, T)[0, 2:].all()
    resting[0, 4] = False
    assert not unreachable(poses, shift, targets, spread, speeds, boxes, resting, awake, T)[0, 4]
    # two particles, the ball awake in the first only: each is judged on its own row
    resting[0, 4] = True
    two = [np.concatenate([a, a]) for a in (poses, shift, targets, spread, speeds, resting)]
    both = unreachable(*two[:5], boxes, two[5], np.concatenate([awake, awake & False]), T)
    assert both.tolist() == [[False, False, False, False, True], [False, False, True, True, True]]


def test_a_turned_box_is_judged_by_its_own_box_and_particles_apart():
    """Box 2 is long (40 cm along its x axis): axis-aligned its end reaches the ball's sweep, turned
    a quarter about z it does not; each particle is judged on its own row."""
    poses, shift, targets, spread, speeds, boxes, resting, awake = _line([0.25], [0.2, 0.02, 0.02], 0.1)
    poses = np.repeat(poses, 2, axis=0)
    poses[1, 2, 3:] = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]
    args = [np.repeat(a, 2, axis=0) for a in (shift, poses[:1], spread, speeds)]
    frozen = unreachable(poses, *args, boxes, np.repeat(resting, 2, 0), np.repeat(awake, 2, 0), T)
    assert frozen[:, 2].tolist() == [False, True]


def test_a_held_object_gliding_past_a_box_does_not_reach_it_where_a_free_one_might_fall_onto_it():
    """The ball passes 4 cm beside box 2 (more than the contact margin, less than a fall in one
    update): held, it is set on its path at every step and cannot touch the box; free, it may."""
    gap = 0.04
    assert FREEZE_MARGIN < gap < FALL
    poses, shift, targets, spread, speeds, boxes, resting, awake = _line([1.0 * T + 0.03 + gap + 0.05], 0.05, 1.0)
    gliding = awake.copy()
    held = unreachable(poses, shift, targets, spread, speeds, boxes, resting, awake, T, gliding=gliding)
    free = unreachable(poses, shift, targets, spread, speeds, boxes, resting, awake, T)
    assert held[0, 2] and not free[0, 2]
    # nearer than the contact margin, even a held one may touch it
    poses[0, 2, 0] = 1.0 * T + 0.03 + 0.5 * FREEZE_MARGIN + 0.05
    assert not unreachable(poses, shift, targets, spread, speeds, boxes, resting, awake, T, gliding=gliding)[0, 2]


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0, 45.0, 30.0])
def test_local_boxes_are_the_objects_own_whatever_their_pose(yaw_deg):
    """Measured exactly, not from the box the object happens to fill at its pose: a box yawed
    45 degrees fills a box half as wide again, which read back in its frame would double."""
    q = [0.0, 0.0, np.sin(np.radians(yaw_deg) / 2), np.cos(np.radians(yaw_deg) / 2)]
    scene = table_scene({"id": "a", "box": {"size": [0.1, 0.2, 0.3]}, "pose": {"position": [0, 0, 1.0]}},
                        {"id": "b", "box": {"size": [0.1, 0.2, 0.3]},
                         "pose": {"position": [0.5, 0, 1.0], "orientation": q}})
    with World(scene) as w:
        w.set_poses(w.get_poses())  # loaded (not parked)
        before = w.get_poses()
        centre, half = local_boxes(w)
        assert np.allclose(w.get_poses(), before, atol=1e-9)  # set back where it was
    assert np.allclose(half[1:], [[0.05, 0.1, 0.15]] * 2, atol=0.005)  # Bullet's margin at most
    assert np.allclose(centre[1:], 0.0, atol=1e-6) and np.all(half[0] == 0.0)  # the static table: none


# -- in the worlds: a frozen object costs nothing and changes nothing ---------------------------------

LINE = table_scene({"id": "near", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.025]}},
                   {"id": "far", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [-0.5, -0.3, TABLE_TOP + 0.025]}},
                   {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.3, 0.0, TABLE_TOP + 0.03]}})


def _inputs(w, poses, vel, reset):
    m = w.num_objects
    return StepInput(poses=poses, velocities=vel, params=np.array([[0.5, 0.0, 0.0, 0.0, 0.5]] * m),
                     modes=np.zeros(m, np.int8), check=np.zeros(m, bool), target=poses.copy(),
                     target_vel=np.zeros((m, 6)), contents=np.zeros((m, m), bool), depenetrate=np.zeros(m, bool),
                     reset=reset)


@pytest.mark.parametrize("freeze", [True, False])
def test_a_ball_rolled_into_a_box_moves_it_while_the_box_it_cannot_reach_is_frozen(freeze):
    with World(LINE, PhysicsSettings(sleeping=True)) as w:
        pw = ParticleWorld(w)
        out = propagate(pw, _inputs(w, w.get_poses(), np.zeros((4, 6)), None), 48, 0.045)
        for _ in range(2):  # at rest at both ends of an update: asleep
            out = propagate(pw, _inputs(w, out.poses, out.velocities, np.zeros(4, bool)), 19, 0.045)
        assert np.all(out.velocities[1:] == 0.0)
        for _ in range(2):  # nothing awake: everything at rest is frozen, and stays so
            out = propagate(pw, _inputs(w, out.poses, out.velocities, np.zeros(4, bool)), 19, 0.045, freeze=freeze)
            assert pw.frozen == ([1, 2, 3] if freeze else [])
        poses, vel = out.poses.copy(), out.velocities.copy()
        poses[3, :3] = [0.07, 0.0, TABLE_TOP + 0.03]  # the ball, rolling at 1 m/s into the near box
        vel[3, :3] = [-1.0, 0, 0]
        inp = _inputs(w, poses, vel, np.array([False, False, False, True]))
        batch = BatchInput(*(None if getattr(inp, f) is None else np.asarray(getattr(inp, f))[None]
                             for f in PER_PARTICLE))
        counts: dict[str, int] = {}
        res = propagate_batch([pw], batch, 19, 0.045, counts=counts, freeze=freeze)  # the ball thaws the near box
        # the far box, 58 cm away: further than a box the ball hits can go in 19 steps (4 x 1 m/s x 79 ms)
        assert counts["frozen"] == (1 if freeze else 0)
        assert np.linalg.norm(res.poses[0, 1, :2] - poses[1, :2]) > 0.01  # the near box was pushed
        assert np.array_equal(res.poses[0, 2], poses[2])  # the far one did not move
        # frozen, the far box stays out of collision detection until thawed: then a ray down onto it hits it
        ray = (np.array([[-0.5, -0.3, 1.5]]), np.array([[-0.5, -0.3, 0.0]]))
        assert pw.frozen == ([2] if freeze else []) and w.ray_test(*ray)[0].tolist() == ([0] if freeze else [2])
        pw.thaw()
        assert pw.frozen == [] and w.ray_test(*ray)[0].tolist() == [2]
        if freeze:
            with World(LINE, PhysicsSettings(sleeping=True)) as w2:  # the same without freezing
                pw2 = ParticleWorld(w2)
                o2 = propagate(pw2, _inputs(w2, w2.get_poses(), np.zeros((4, 6)), None), 48, 0.045)
                for _ in range(2):
                    o2 = propagate(pw2, _inputs(w2, o2.poses, o2.velocities, np.zeros(4, bool)), 19, 0.045)
                ref = propagate_batch([pw2], batch, 19, 0.045)
            assert np.allclose(res.poses[0, :, :3], ref.poses[0, :, :3], atol=1e-6)


def test_a_held_object_is_alone_only_when_its_glide_comes_near_nothing():
    """Boxes ``lo, hi`` of two dynamic objects (1: held, gliding; 2: another) and a static one (0)
    in two particles; the held object is alone in a particle only where it keeps ``margin`` off
    the other object's sweep, the static box and the floor."""
    lo = np.zeros((2, 3, 3))
    hi = np.zeros((2, 3, 3))
    lo[:, 1], hi[:, 1] = [0.0, 0.0, 1.0], [0.1, 0.1, 1.1]  # the held one's glide, 1 m up
    lo[:, 2], hi[:, 2] = [0.3, 0.0, 1.0], [0.4, 0.1, 1.1]  # another, 20 cm from it...
    lo[1, 2, 0] = 0.1 + FREEZE_MARGIN - 0.001  # ...or 1.9 cm from it
    gliding = np.array([[False, True, False]] * 2)
    dyn = np.array([False, True, True])
    no_statics = np.zeros((2, 0, 2, 3))
    got = alone(lo, hi, gliding, dyn, no_statics, np.zeros(2))
    assert got.tolist() == [[False, True, False], [False, False, False]]
    table = np.array([[[-1.0, -1.0, 0.0], [1.0, 1.0, 0.99]]] * 2)[:, None]  # (2, 1, 2, 3): top 1 cm below it
    assert not alone(lo, hi, gliding, dyn, table, None)[0, 1]
    table[:, :, 1, 2] = 1.0 - FREEZE_MARGIN - 0.001  # 2.1 cm below it
    assert alone(lo, hi, gliding, dyn, table, None)[0, 1]
    assert not alone(lo, hi, gliding, dyn, no_statics, np.array([1.0 - FREEZE_MARGIN + 0.001] * 2))[0, 1]  # the floor
    assert not alone(lo, hi, gliding & False, dyn, no_statics, None).any()  # only held ones
