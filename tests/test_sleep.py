import numpy as np
import pytest

from helpers import TABLE_TOP, table_scene
from physics.settings import PhysicsSettings
from physics.sleep import asleep, near, sleep, touching, wake
from physics.world import World

SCENE = table_scene({"id": "a", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.025]}},
                    {"id": "b", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0, 0, TABLE_TOP + 0.075]}},
                    {"id": "c", "box": {"size": [0.05, 0.05, 0.05]}, "pose": {"position": [0.3, 0, TABLE_TOP + 0.025]}})


def test_sleeping_bodies_stay_put_until_woken_and_contacts_name_the_stack():
    with World(SCENE, PhysicsSettings(sleeping=True)) as w:
        w.step(60)
        assert touching(w, [1]) == [0, 2]  # a rests on the table and carries b; c is elsewhere
        assert near(w, [3], margin=0.01) == [0] and near(w, [1], margin=0.01) == [0, 2]  # the table, b
        sleep(w, [1, 2, 3])
        w.step(5)  # Bullet settles the islands' state in the steps that follow
        assert asleep(w, [1, 2, 3]) == [1, 2, 3]
        lifted = w.get_poses([3])
        lifted[0, 2] += 0.05
        w.set_poses(lifted, [3])
        w.step(24)
        assert w.get_poses([3])[0, 2] > TABLE_TOP + 0.07  # a reset does not wake it: still in the air
        wake(w, [3])
        w.step(60)
        assert w.get_poses([3])[0, 2] == pytest.approx(TABLE_TOP + 0.025, abs=2e-3)  # woken, it fell
        assert asleep(w, [1, 2]) == [1, 2]


def test_without_sleeping_nothing_sleeps():
    with World(SCENE) as w:  # PhysicsSettings().sleeping is False
        w.step(240)
        assert asleep(w, [1, 2, 3]) == []
        assert np.all(w.get_velocities([1, 2, 3]) != 0.0, axis=1).any()
