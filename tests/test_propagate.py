from dataclasses import replace

import numpy as np
import pytest

from actions.modes import FREE, HELD
from estimator.propagate import (PER_PARTICLE, BatchInput, ParticleWorld, StepInput, depenetrate, propagate,
                                 propagate_batch)
from physics.world import World

from helpers import TABLE_TOP, table_scene

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
    batch = BatchInput(*(np.stack([getattr(r, f) for r in rows]) for f in PER_PARTICLE), np.zeros(3, bool))
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
