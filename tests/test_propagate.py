from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD
from estimator.worlds.batch import PER_PARTICLE, BatchInput, ParticleWorld, StepInput
from estimator.worlds.held import depenetrate
from estimator.worlds.propagate import propagate, propagate_batch
from helpers import TABLE_TOP, table_scene
from physics.world import PhysicsSettings, World

SCENE = table_scene({"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "mass": 0.5,
                     "pose": {"position": [0, 0, TABLE_TOP + 0.05]}},
                    {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.4, 0.2, TABLE_TOP + 0.03]}})


def inputs(w, **kw):
    m = w.num_objects
    base = dict(poses=w.get_poses(), velocities=np.zeros((m, 6)),
                params=np.array([[0.5, 0.0, 0.0, 0.0, 0.5]] * m), modes=np.zeros(m, np.int8),
                check=np.zeros(m, bool), target=w.get_poses(), target_vel=np.zeros((m, 6)),
                contents=np.zeros((m, m), bool), depenetrate=np.zeros(m, bool))
    base.update(kw)
    return StepInput(**base)


@pytest.mark.parametrize("lazy", [False, True])
def test_divergence_switches_a_free_object_to_held(lazy):
    with World(SCENE) as w:
        pw = ParticleWorld(w)
        target = w.get_poses()
        target[1, 2] += 0.2  # perceived 20 cm above where it rests
        out = propagate(pw, inputs(w, check=np.array([False, True, False]), target=target), 19, 0.045,
                        lazy=lazy)
        assert out.modes.tolist() == [FREE, HELD, FREE] and out.finite
        assert np.allclose(out.poses[1], target[1], atol=1e-9)  # overridden: ends at the perception
        assert out.max_divergence[1] > 0.045
        # a small divergence (1 cm float) stays plausible and the box rests on the table
        target[1, 2] = TABLE_TOP + 0.06
        start = target.copy()
        start[1, 2] = TABLE_TOP + 0.05
        out = propagate(pw, inputs(w, poses=start, check=np.array([False, True, False]), target=target), 19,
                        0.045, lazy=lazy)
        assert out.modes[1] == FREE and out.poses[1, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)
        assert 0.005 < out.max_divergence[1] < 0.02


@pytest.mark.parametrize("lazy", [False, True])
def test_a_rolling_ball_tested_against_its_detection_carried_on_stays_free(lazy):
    # the ball, started where its detection was at the update's start, rolling at 0.9 m/s along x,
    # covers 7 cm in 19 steps and ends at its detection (the target)
    with World(SCENE) as w:
        pw = ParticleWorld(w)
        vel = np.zeros((3, 6))
        vel[2] = [0.9, 0.0, 0.0, 0.0, 0.9 / 0.03, 0.0]
        target = w.get_poses()
        target[2, 0] += 0.9 * 19 / 240
        step = inputs(w, velocities=vel, check=np.array([False, False, True]), target=target, target_vel=vel.copy())
        fixed = propagate(pw, step, 19, 0.045, lazy=lazy)
        assert fixed.modes[2] == HELD  # against the fixed detection, 7 cm away at the start: implausible
        assert np.allclose(fixed.poses[2], step.target[2], atol=1e-9)
        moved = propagate(pw, step, 19, 0.045, lazy=lazy, moving=True)
        assert moved.modes[2] == FREE and moved.max_divergence[2] < 0.01  # rolling as the detection goes on
        assert moved.poses[2, 0] - step.poses[2, 0] == pytest.approx(0.9 * 19 / 240, abs=0.01)
        assert moved.velocities[2, 0] == pytest.approx(0.9, abs=0.05)
        # a detection that runs away at 0.9 m/s from a ball at rest: held from the step it diverges
        # on, it follows the moving target and ends at it
        still = inputs(w, check=np.array([False, False, True]), target=target, target_vel=vel.copy())
        chased = propagate(pw, still, 60, 0.045, lazy=lazy, moving=True)
        assert chased.modes[2] == HELD
        assert np.allclose(chased.poses[2, :3], target[2, :3], atol=1e-6)
        assert chased.velocities[2, 0] == pytest.approx(0.9, abs=1e-6)


def test_held_object_glides_to_its_target_and_runaway_is_flagged():
    with World(SCENE) as w:
        pw = ParticleWorld(w)
        target = w.get_poses()
        target[1, :3] += [0.1, 0.0, 0.1]
        out = propagate(pw, inputs(w, modes=np.array([FREE, HELD, FREE], np.int8), target=target), 24, 0.045)
        assert np.allclose(out.poses[1], target[1], atol=1e-9)
        v = inputs(w).velocities
        v[2, :3] = [500.0, 0, 0]
        out = propagate(pw, inputs(w, velocities=v), 2, 0.045)
        assert not out.finite


def test_depenetrate_pushes_a_sunk_box_out_of_the_table():
    with World(SCENE) as w:
        p = w.get_poses([1])
        p[0, 2] -= 0.03  # 3 cm into the table
        w.set_poses(p, [1])
        depenetrate(w, [1])
        assert w.get_poses([1])[0, 2] == pytest.approx(TABLE_TOP + 0.05, abs=2e-3)


def test_a_batch_of_worlds_gives_each_particle_what_it_gets_alone():
    # three particles: dropped from another height, held and moved, checked against a target far
    # above; each row of the batch must come out as if propagated alone (sharding changes nothing)
    with World(SCENE) as ref:
        base = inputs(ref, reset=np.ones(3, bool))
    rows = []
    for j in range(3):
        poses = base.poses.copy()
        poses[1, 2] += 0.05 * j
        target = poses.copy()
        modes, check = base.modes.copy(), base.check.copy()
        if j == 1:
            modes[1] = HELD
            target[1, :3] += [0.05, 0.0, 0.1]
        if j == 2:
            check[2] = True
            target[2, 2] += 0.2
        rows.append(replace(base, poses=poses, target=target, modes=modes, check=check))
    alone = []
    for inp in rows:
        with World(SCENE) as w:
            alone.append(propagate(ParticleWorld(w), inp, 30, 0.045, lazy=True))
    batch = BatchInput(*(None if getattr(rows[0], f) is None else np.stack([getattr(r, f) for r in rows])
                         for f in PER_PARTICLE), np.zeros(3, bool))
    worlds = [World(SCENE) for _ in range(3)]
    try:
        out = propagate_batch([ParticleWorld(w) for w in worlds], batch, 30, 0.045, lazy=True)
    finally:
        for w in worlds:
            w.close()
    for j in range(3):
        assert np.array_equal(out.poses[j], alone[j].poses) and np.array_equal(out.velocities[j], alone[j].velocities)
        assert np.array_equal(out.modes[j], alone[j].modes) and np.array_equal(out.aabbs[j], alone[j].aabbs)
        assert np.array_equal(out.max_divergence[j], alone[j].max_divergence)
    assert out.modes[1, 1] == HELD and out.modes[2, 2] == HELD and out.modes[0].tolist() == [FREE] * 3
    assert out.finite.all()


# -- sleeping: resting objects cost nothing, and wake as a world that never slept would move them ---------

STACK = table_scene({"id": "a", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.025]}},
                    {"id": "b", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.075]}},
                    {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.4, 0.2, TABLE_TOP + 0.03]}})


def _settled(w):
    """Let the stack settle and rest for two updates (so that, with sleeping, it falls asleep)."""
    pw = ParticleWorld(w)
    out = propagate(pw, inputs(w), 48, 0.045)
    for _ in range(2):
        out = propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities, reset=np.zeros(4, bool)), 19, 0.045)
    return pw, out


def _both(event):
    """Run ``event(pw, w, out, freeze) -> output`` in a world that sleeps, freezing what nothing can
    reach (as the estimator does) and not, and in one that never sleeps."""
    res = []
    for sleeping, freeze in ((True, True), (True, False), (False, False)):
        with World(STACK, PhysicsSettings(sleeping=sleeping)) as w:
            pw, out = _settled(w)
            if sleeping:  # the resting objects are asleep: they read back exactly zero velocity
                assert np.all(out.velocities[:, 1:] == 0.0)
            res.append(event(pw, w, out, freeze))
    assert np.allclose(res[0][:, :3], res[1][:, :3], atol=1e-3)  # freezing changes nothing that matters
    return res[1:]


def test_a_sleeping_object_that_is_reset_falls():
    def event(pw, w, out, freeze):
        poses = out.poses.copy()
        poses[3, 2] += 0.05  # the ball, 5 cm up
        reset = np.array([False, False, False, True])
        return propagate(pw, inputs(w, poses=poses, velocities=out.velocities, reset=reset), 48, 0.045, freeze=freeze).poses
    slept, awake = _both(event)
    assert slept[3, 2] == pytest.approx(TABLE_TOP + 0.03, abs=2e-3)  # not left floating
    assert np.allclose(slept[:, :3], awake[:, :3], atol=1e-3)


def test_a_sleeping_object_whose_support_is_removed_falls():
    def event(pw, w, out, freeze):
        poses = out.poses.copy()
        poses[1, :3] = [0.5, -0.2, TABLE_TOP + 0.025]  # the bottom block is taken away
        reset = np.array([False, True, False, False])
        return propagate(pw, inputs(w, poses=poses, velocities=out.velocities, reset=reset), 48, 0.045, freeze=freeze).poses
    slept, awake = _both(event)
    assert slept[2, 2] == pytest.approx(TABLE_TOP + 0.025, abs=2e-3)  # the top block fell onto the table
    assert np.allclose(slept[:, :3], awake[:, :3], atol=1e-3)


def test_a_sleeping_object_that_is_hit_moves():
    def event(pw, w, out, freeze):
        poses, vel = out.poses.copy(), out.velocities.copy()
        poses[3, :3] = [0.15, 0.0, TABLE_TOP + 0.03]  # the ball, rolling at 1.5 m/s into the stack
        vel[3, :3] = [-1.5, 0, 0]
        reset = np.array([False, False, False, True])
        return propagate(pw, inputs(w, poses=poses, velocities=vel, reset=reset), 48, 0.045, freeze=freeze).poses
    slept, awake = _both(event)
    assert np.linalg.norm(slept[1:3, :2], axis=1).min() > 0.01  # the blocks were pushed
    assert np.allclose(slept[:, :3], awake[:, :3], atol=5e-3)


def test_a_sleeping_object_on_a_held_object_moves_with_it():
    def event(pw, w, out, freeze):
        target = out.poses.copy()
        target[1, 0] += 0.03  # the bottom block is held and slid 3 cm
        modes = np.array([FREE, HELD, FREE, FREE], np.int8)
        return propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities, modes=modes, target=target,
                                    reset=np.zeros(4, bool)), 24, 0.045, freeze=freeze).poses
    slept, awake = _both(event)
    assert slept[2, 0] > 0.01  # the top block rode along (dragged by friction: a millimetre either way)
    assert np.allclose(slept[:, :3], awake[:, :3], atol=2e-3)


def test_a_settled_load_that_is_frozen_stays_exactly_where_it_was_loaded():
    """A resampled particle's resting stack, loaded asleep into another world and frozen in the same
    update (nothing can reach it), does not move at all: Bullet still moves a body put to sleep in
    its next step (out of collision it would fall 0.17 mm), so it is set back after that step."""
    with World(STACK, PhysicsSettings(sleeping=True)) as donor, World(STACK, PhysicsSettings(sleeping=True)) as w:
        _, rest = _settled(donor)
        pw, own = _settled(w)
        vel = own.velocities.copy()
        vel[1:3, 0] = 0.2  # the world's own stack is sliding (awake) when the donor's is loaded
        propagate(pw, inputs(w, poses=own.poses, velocities=vel, reset=np.array([False, True, True, False])), 19, 0.045)
        poses = rest.poses.copy()
        poses[1:3, 0] += 0.1  # the donor's stack, 10 cm along
        inp = inputs(w, poses=poses, velocities=np.zeros((4, 6)), reset=np.array([False, True, True, False]),
                     settled=np.full(4, True))
        out = propagate(pw, inp, 19, 0.045, freeze=True)
        assert {1, 2} <= set(pw.frozen)
        assert np.abs(out.poses[1:3] - poses[1:3]).max() < 1e-9 and np.all(out.velocities[1:3] == 0.0)


def test_what_a_frozen_object_reads_back_is_what_pybullet_holds():
    """Objects out of collision for an update are not read again (they cannot have moved): what the
    update returns for them is still, bit for bit, what pybullet holds, over updates that freeze
    them, move the ball about (awake, away from them) and reload one of them asleep."""
    with World(STACK, PhysicsSettings(sleeping=True)) as w:
        pw, out = _settled(w)
        frozen = 0
        for j in range(6):
            poses, vel = out.poses.copy(), out.velocities.copy()
            reset = np.array([False, False, j == 4, True])
            poses[3, :3] = [0.4 - 0.05 * j, 0.2, TABLE_TOP + 0.1]  # the ball dropped, away from the stack
            poses[2, 0] += 0.001 * (j == 4)  # the top block loaded asleep 1 mm along (frozen too)
            vel[3] = 0.0
            out = propagate(pw, inputs(w, poses=poses, velocities=vel, reset=reset, settled=reset & (j == 4)), 19,
                            0.045, lazy=True, freeze=True)
            frozen += len(pw.frozen)
            assert j != 4 or 2 in pw.frozen
            if j == 4:  # loaded asleep and frozen: it did not move at all
                assert np.abs(out.poses[2] - poses[2]).max() < 1e-9 and np.all(out.velocities[2] == 0.0)
            p, v, b = w.read_state()
            assert np.array_equal(out.poses[1:], p[1:]) and np.array_equal(out.velocities[1:], v[1:])
            assert np.array_equal(out.aabbs[1:], b[1:])
        assert frozen >= 8  # the stack was frozen in most updates


def test_a_held_object_that_nothing_can_touch_ends_at_its_glides_end_and_back_in_collision(monkeypatch):
    """The ball held, picked up 30 cm off the table, then carried 20 cm along in the air far from
    the stack: with the freeze on it is out of collision for that second update and placed at its
    glide's end only; it ends where it does when set at every step, with the same velocity, and
    rays hit it again after."""
    from estimator.worlds import held

    alone, glide = [], held.HeldObjects.glide
    monkeypatch.setattr(held.HeldObjects, "glide", lambda self, *a: alone.append(a[5]) or glide(self, *a))
    ends = []
    for freeze in (False, True):
        with World(STACK, PhysicsSettings(sleeping=True)) as w:
            pw, out = _settled(w)
            target = out.poses.copy()
            modes = np.array([FREE, FREE, FREE, HELD], np.int8)
            for lift in ([0.0, 0.0, 0.3], [0.0, 0.2, 0.0]):  # picked up off the table, then carried in the air
                target[3, :3] += lift
                out = propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities, modes=modes, target=target,
                                           reset=np.zeros(4, bool)), 24, 0.045, lazy=True, freeze=freeze)
            x, y = target[3, :2]
            ends.append((out.poses, out.velocities, w.ray_test([[x, y, 2.0]], [[x, y, 0.0]])[0][0]))
    assert alone == [None, None, None, 3]  # set at every step off the table or without the freeze, else alone
    (p0, v0, _), (p1, v1, hit) = ends
    assert hit == 3  # back in collision: rays see it
    assert np.allclose(p1[3], p0[3], atol=1e-12) and np.allclose(v1[3], v0[3], atol=1e-12)
    assert np.allclose(p1[3, :3], target[3, :3], atol=1e-9) and v1[3, 1] > 1.0  # at its target, gliding
    assert np.allclose(p1[1:3], p0[1:3], atol=1e-9)  # the stack did not notice


def test_a_resting_stack_stays_put_when_reloaded_every_update():
    """Loading every object from the arrays at every update (as after resampling) must not make a
    resting stack creep more than in a persistent world that never sleeps (Bullet's own creep of a
    stack of blocks: about 1.6 mm in 4 s); left alone, a sleeping stack does not move at all."""
    creep = {}
    for sleeping, reload in ((True, True), (True, False), (False, False)):
        settings = PhysicsSettings(sleeping=sleeping, solver_residual_threshold=1e-4)
        with World(STACK, settings) as w:
            pw, out = _settled(w)
            start = out.poses.copy()
            for _ in range(50):
                out = propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities,
                                           reset=np.full(4, reload)), 19, 0.045)
            creep[sleeping, reload] = np.abs(out.poses[:, :3] - start[:, :3]).max()
    assert creep[True, False] < 1e-6
    assert creep[True, True] < creep[False, False] + 2e-4
    assert creep[False, False] < 5e-3


def test_an_object_loaded_at_rest_that_stays_at_rest_sleeps_in_that_update_and_one_still_moving_does_not():
    """With ``sleep_loads``, an object the update loads (a teleport: the ball put 10 cm along the table,
    at rest) and that is still after a few steps (:data:`~estimator.worlds.resting.PROBE_STEPS`) is
    put to sleep then: it reads back exactly zero velocity at the end of that update and through the
    next (without, it is awake through both). Loaded 5 cm up, it is falling by then and stays awake."""
    for lift, sleep_loads in ((0.0, True), (0.0, False), (0.05, True)):
        with World(STACK, PhysicsSettings(sleeping=True)) as w:
            pw, out = _settled(w)
            poses = out.poses.copy()
            poses[3, :3] += [0.1, 0.0, lift]
            load = propagate(pw, inputs(w, poses=poses, velocities=np.zeros((4, 6)),
                                        reset=np.array([False, False, False, True])), 19, 0.045, sleep_loads=sleep_loads)
            asleep = lift == 0.0 and sleep_loads
            assert np.all(load.velocities[3] == 0.0) == asleep, (lift, sleep_loads)
            out = propagate(pw, inputs(w, poses=load.poses, velocities=load.velocities, reset=np.zeros(4, bool)), 19,
                            0.045, sleep_loads=sleep_loads)
            assert np.all(out.velocities[3] == 0.0) == asleep, (lift, sleep_loads)
            assert out.poses[3, 2] == pytest.approx(TABLE_TOP + 0.03, abs=2e-3)  # on the table either way


def test_a_settled_state_is_loaded_asleep_and_an_edited_one_awake():
    """After resampling, a particle's world takes another's resting state: loaded as settled it stays
    asleep (stepping skips it); loaded as an edit it is woken (and reads back a velocity)."""
    with World(STACK, PhysicsSettings(sleeping=True)) as donor, World(STACK, PhysicsSettings(sleeping=True)) as w:
        _, rest = _settled(donor)
        pw, _ = _settled(w)
        poses = rest.poses.copy()
        poses[1:3, 0] += 0.1  # the donor's stack, 10 cm along
        for settled, asleep in ((True, True), (False, False)):
            inp = inputs(w, poses=poses, velocities=np.zeros((4, 6)), reset=np.array([False, True, True, False]),
                         settled=np.full(4, settled))
            out = propagate(pw, inp, 19, 0.045)
            assert np.all(out.velocities[1:3] == 0.0) == asleep
            assert np.allclose(out.poses[1:3, :3], poses[1:3, :3], atol=1e-3)  # a resting stack either way


def test_a_settled_object_whose_support_was_moved_is_woken():
    """A resampled particle's resting stack, its bottom block then jittered 2 cm aside: the top block
    (settled, loaded asleep) must not float where its support was."""
    with World(STACK, PhysicsSettings(sleeping=True)) as donor, World(STACK, PhysicsSettings(sleeping=True)) as w, \
            World(STACK, PhysicsSettings(sleeping=False)) as never:
        _, rest = _settled(donor)
        poses = rest.poses.copy()
        poses[1:3, 0] += 0.1   # the donor's stack, 10 cm along
        poses[1, 0] += 0.06    # its bottom block jittered 6 cm further: the top one has nothing under it
        res = []
        for world, settled in ((w, np.array([False, False, True, False])), (never, None)):
            pw, out = _settled(world)
            apart = out.poses.copy()  # the world's own particle had the two blocks apart, asleep
            apart[2, :3] = [-0.3, -0.2, TABLE_TOP + 0.025]
            for load in (True, False, False):
                out = propagate(pw, inputs(world, poses=apart, velocities=out.velocities,
                                           reset=np.array([False, load, load, False])), 19, 0.045)
                apart = out.poses
            if settled is not None:
                assert np.all(out.velocities[1:3] == 0.0)  # asleep
            inp = inputs(world, poses=poses, velocities=np.zeros((4, 6)), reset=np.array([False, True, True, False]),
                         settled=settled)
            res.append(propagate(pw, inp, 12, 0.045).poses)  # 50 ms: falling 12 mm
        assert res[0][2, 2] < TABLE_TOP + 0.075 - 0.008  # falling, not floating
        # as in a world that never slept, but for the step a woken body spends still (g t dt: 2 mm)
        assert np.allclose(res[0][:, :3], res[1][:, :3], atol=3e-3)


def test_objects_placed_at_rest_in_a_world_never_stepped_sleep_from_its_first_step():
    """In a world that has never stepped, every body is awake: loaded where the stack rests, it rings
    as Bullet makes its contacts afresh. Entries the batch gives as settled there (placed at rest by
    the model, :func:`~estimator.model.regularisation.placed_at_rest`) sleep from the first step:
    they end the update exactly where they were loaded, at zero velocity, and may be frozen; the
    same entries not settled are stepped awake (and read back a velocity)."""
    with World(STACK, PhysicsSettings(sleeping=True)) as donor:
        _, rest = _settled(donor)
    for settled in (True, False):
        with World(STACK, PhysicsSettings(sleeping=True)) as w:
            pw = ParticleWorld(w)
            propagate(pw, inputs(w, poses=rest.poses, velocities=np.zeros((4, 6))), 0, 0.045)  # loads only
            inp = inputs(w, poses=rest.poses, velocities=np.zeros((4, 6)), reset=np.zeros(4, bool),
                         settled=np.array([False, True, True, settled]))
            out = propagate(pw, inp, 19, 0.045, freeze=True, sleep_loads=True)
            assert np.abs(out.poses[1:3] - rest.poses[1:3]).max() < 1e-9 and np.all(out.velocities[1:3] == 0.0)
            assert {1, 2, 3} <= set(pw.frozen) if settled else 3 not in pw.frozen
            if not settled:  # the ball, awake since it was made, is stepped: not bit for bit where it was
                assert not np.array_equal(out.poses[3], rest.poses[3]) or np.any(out.velocities[3] != 0.0)


def test_an_object_placed_at_rest_that_something_loaded_beside_it_wakes_is_stepped():
    """A settled entry in a world never stepped next to an object the update loads awake (within
    :data:`~estimator.worlds.resting.SETTLED_REACH`) is woken with it, as a settled load is: the top
    block, its bottom block loaded 6 cm aside (1 cm from it), falls; it does not float."""
    with World(STACK, PhysicsSettings(sleeping=True)) as donor:
        _, rest = _settled(donor)
    with World(STACK, PhysicsSettings(sleeping=True)) as w:
        pw = ParticleWorld(w)
        propagate(pw, inputs(w, poses=rest.poses, velocities=np.zeros((4, 6))), 0, 0.045)
        poses = rest.poses.copy()
        poses[1, 0] += 0.06  # the bottom block taken from under the top one
        inp = inputs(w, poses=poses, velocities=np.zeros((4, 6)), reset=np.array([False, True, False, False]),
                     settled=np.array([False, False, True, True]))
        out = propagate(pw, inp, 48, 0.045, freeze=True, sleep_loads=True)
        assert out.poses[2, 2] < rest.poses[2, 2] - 0.02  # it fell


@pytest.mark.parametrize("held_for, freeze", [(0.2, True), (2.5, False), (2.5, True)])
def test_an_object_let_go_at_rest_in_the_air_falls_however_long_it_was_held(held_for, freeze):
    """The box lifted 10 cm and held still (its hand's target at rest), then let go: it falls onto
    the table in the next 0.2 s. Let go with the zero velocity of a still hand, the freezing of
    objects at rest would take it for one asleep (exactly zero velocity) and freeze it in the air
    (it did); held over 2 s, Bullet's own clock would put it to sleep (it moved slower than 0.1 m/s
    all that time) but for the wake every update gives what it holds."""
    with World(SCENE, PhysicsSettings(sleeping=True)) as w:
        pw = ParticleWorld(w)
        rest = w.get_poses()
        target = rest.copy()
        target[1, 2] += 0.10
        modes = np.array([FREE, HELD, FREE], np.int8)
        out = propagate(pw, inputs(w, modes=modes, target=target), 24, 0.045, freeze=freeze, sleep_loads=True)
        for _ in range(int(round(held_for / 0.1))):
            out = propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities, modes=modes, target=target,
                                       reset=np.zeros(3, bool)), 24, 0.045, freeze=freeze, sleep_loads=True)
        assert out.poses[1, 2] == pytest.approx(target[1, 2], abs=1e-9) and np.all(out.velocities[1] == 0.0)
        free = np.array([FREE, FREE, FREE], np.int8)
        out = propagate(pw, inputs(w, poses=out.poses, velocities=out.velocities, modes=free, target=out.poses,
                                   reset=np.zeros(3, bool)), 48, 0.045, freeze=freeze, sleep_loads=True)
        assert out.poses[1, 2] == pytest.approx(rest[1, 2], abs=3e-3)  # on the table, not in the air
