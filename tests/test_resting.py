"""estimator.worlds.resting: when poses taken a window apart are at rest; sleeping what is still."""
import numpy as np
import pybullet as pb
import pytest

from estimator.worlds.resting import REST_SPEED, REST_SPIN, at_rest, sleep_settling, sleep_still
from helpers import table_scene
from physics.sleep import asleep
from physics.transforms import quat_from_rotvec
from physics.world import PhysicsSettings, World


def test_at_rest_compares_the_average_speed_and_spin_over_the_window_with_the_thresholds():
    before = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]])
    dt = 0.05
    slow = before.copy()
    slow[0, 0] += 0.9 * REST_SPEED * dt
    slow[1, 3:] = quat_from_rotvec(np.array([0.0, 0.9 * REST_SPIN * dt, 0.0]))
    assert at_rest(before, slow, dt)
    moving = slow.copy()
    moving[0, 0] = 1.1 * REST_SPEED * dt
    assert not at_rest(before, moving, dt)
    turning = slow.copy()
    turning[1, 3:] = -quat_from_rotvec(np.array([1.1 * REST_SPIN * dt, 0.0, 0.0]))  # the sign of q is no turn
    assert not at_rest(before, turning, dt)
    assert at_rest(before[:0], before[:0], dt)


@pytest.mark.parametrize("factor, sleeps", [(0.9, True), (1.1, False)])
def test_sleep_still_sleeps_a_body_slower_than_the_scaled_thresholds_and_no_other(factor, sleeps):
    """Balls in the air given speeds (or spins) about the thresholds times the scale: those below both
    are put to sleep (Bullet still moves a body put to sleep in its next step; after the one
    following, they read back zero velocity), the others stay awake."""
    scale = 0.25
    scene = table_scene(*({"id": f"b{i}", "sphere": {"radius": 0.02}, "pose": {"position": [0.2 * i, 0.0, 1.5]}}
                          for i in range(2)))
    with World(scene, PhysicsSettings(sleeping=True)) as w:
        lin = [factor * REST_SPEED * scale, 0.0, 0.0]
        ang = [0.0, factor * REST_SPIN * scale, 0.0]
        pb.resetBaseVelocity(w.uids[1], lin, [0.0, 0.0, 0.0], physicsClientId=w.client)  # moving
        pb.resetBaseVelocity(w.uids[2], [0.0, 0.0, 0.0], ang, physicsClientId=w.client)  # turning
        count = [0]
        sleep_still(w.client, [w.uids[1], w.uids[2]], scale, count)
        assert count[0] == (2 if sleeps else 0)
        w.step(2)
        assert asleep(w, [1, 2]) == ([1, 2] if sleeps else [])


def test_a_slow_body_that_has_not_sped_up_since_the_probe_sleeps_and_one_speeding_up_does_not():
    """Two balls in the air, slower than the rest thresholds but not than the probe's scaled ones:
    not put to sleep at the probe, handed on; some steps later (here, reset to the speeds they would
    then have), the one that slowed down sleeps, the one that sped up does not."""
    scene = table_scene(*({"id": f"b{i}", "sphere": {"radius": 0.02}, "pose": {"position": [0.2 * i, 0.0, 1.5]}}
                          for i in range(2)))
    with World(scene, PhysicsSettings(sleeping=True, gravity=0.0)) as w:
        uids = [w.uids[1], w.uids[2]]
        for uid in uids:
            pb.resetBaseVelocity(uid, [0.5 * REST_SPEED, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=w.client)
        count = [0]
        slow = sleep_still(w.client, uids, 0.1, count)
        assert count[0] == 0 and [u for u, _, _ in slow] == uids
        pb.resetBaseVelocity(uids[0], [0.3 * REST_SPEED, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=w.client)
        pb.resetBaseVelocity(uids[1], [0.6 * REST_SPEED, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=w.client)
        sleep_settling(w.client, slow, count)
        assert count[0] == 1
        w.step(2)
        assert asleep(w, [1, 2]) == [1]
