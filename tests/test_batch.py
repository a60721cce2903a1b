"""estimator.worlds.batch: what a run of the worlds takes and gives, and a slot's world."""
import dataclasses

import numpy as np

from estimator.worlds.batch import PARAM_NAMES, PER_PARTICLE, BatchInput, ParticleWorld
from helpers import TABLE_TOP, table_scene
from physics.world import World

BOX = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0, 0, TABLE_TOP + 0.03]}}
PARAMS = np.tile([0.5, 0.001, 0.0, 0.1, 0.2], (2, 1))  # the table's row and the box's (PARAM_NAMES)


def test_the_per_particle_fields_are_the_batch_inputs_but_the_visibility_query():
    names = [f.name for f in dataclasses.fields(BatchInput)]
    assert set(PER_PARTICLE) == set(names) - {"vis_query"} and len(PARAM_NAMES) == 5


def test_a_particle_world_applies_only_the_parameters_that_changed():
    with World(table_scene(BOX)) as w:
        pw = ParticleWorld(w)
        params = PARAMS.copy()
        pw.apply_params(params)
        assert np.isclose(w.get_dynamics(1)["lateral_friction"], 0.5) and np.isclose(w.get_dynamics(1)["mass"], 0.2)
        calls = []
        w.set_dynamics = lambda i, **kw: calls.append(i)  # what the next calls change
        pw.apply_params(params.copy())
        assert calls == []  # the same values: nothing set
        params[1, 0] = 0.9
        pw.apply_params(params)
        assert calls == [1]  # only the object whose row changed


def test_thawing_puts_frozen_objects_back_in_collision_but_not_one_parked_since():
    boxes = [{"id": f"b{j}", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0.3 * j, 0, TABLE_TOP + 0.03]}}
             for j in range(2)]
    with World(table_scene(*boxes)) as w:
        w.set_poses(w.get_poses())  # loaded, not parked
        pw = ParticleWorld(w)
        w.set_colliding([1, 2], False)
        pw.frozen = [1, 2]
        poses = w.get_poses()
        poses[2, 2] = -100.0  # box 2 parked while frozen
        w.set_poses(poses)
        assert w.is_parked(2)

        def ray(x):
            return w.ray_test(np.array([[x, 0, 1.5]]), np.array([[x, 0, 0.0]]))[0].tolist()
        assert ray(0.0) == [0]  # frozen: the ray goes through box 1 to the table
        pw.thaw([2])
        assert pw.frozen == [1] and w.is_parked(2)
        pw.thaw()
        assert pw.frozen == [] and ray(0.0) == [1]
        at = w.get_poses()[2, :3]  # where the parked box is: rays and bodies go through it
        assert w.ray_test((at + [0, 0, 1.0])[None], (at - [0, 0, 1.0])[None])[0].tolist() == [-1]
        w.set_colliding([2], True)  # (what an unguarded thaw would do: the ray would then hit it)
        assert w.ray_test((at + [0, 0, 1.0])[None], (at - [0, 0, 1.0])[None])[0].tolist() == [2]


def test_a_read_takes_the_skipped_objects_from_the_last_read_and_asks_pybullet_the_rest():
    boxes = [{"id": f"b{j}", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0.3 * j, 0, TABLE_TOP + 0.03]}}
             for j in range(3)]
    with World(table_scene(*boxes)) as w:
        w.set_poses(w.get_poses())
        pw = ParticleWorld(w)
        first = pw.read()
        assert first == w.read_raw(pw.dynamic)
        poses = w.get_poses()
        poses[1:, 0] += 0.05  # every box moves: a skipped one is the caller's promise that it did not
        w.set_poses(poses)
        fresh = w.read_raw(pw.dynamic)
        p, v, b = pw.read({2})
        assert p[7:14] == first[0][7:14] and b[6:12] == first[2][6:12]  # box 2 (the second dynamic): as last read
        assert p[:7] == fresh[0][:7] and p[14:] == fresh[0][14:] and b[12:] == fresh[2][12:] and v == fresh[1]
        pw.forget()
        assert pw.read({2}) == fresh  # nothing to take it from: all asked of pybullet


def test_a_frozen_object_gets_its_new_parameters_once_it_is_no_longer_skipped():
    with World(table_scene(BOX)) as w:
        pw = ParticleWorld(w)
        params = PARAMS.copy()
        pw.apply_params(params)
        new = params.copy()
        new[1, 0] = 0.9
        pw.apply_params(new, [1])  # frozen: not yet
        assert np.isclose(w.get_dynamics(1)["lateral_friction"], 0.5)
        pw.apply_params(new.copy(), [1])
        assert np.isclose(w.get_dynamics(1)["lateral_friction"], 0.5)
        pw.apply_params(new.copy())  # thawed: the same values as before, now applied
        assert np.isclose(w.get_dynamics(1)["lateral_friction"], 0.9)
