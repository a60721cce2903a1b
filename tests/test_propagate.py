import numpy as np
import pytest

from actions.modes import FREE, HELD
from estimator.propagate import ParticleWorld, StepInput, depenetrate, propagate
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
