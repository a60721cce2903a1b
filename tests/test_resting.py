"""estimator.worlds.resting: when poses taken a window apart are at rest."""
import numpy as np

from estimator.worlds.resting import REST_SPEED, REST_SPIN, at_rest
from physics.transforms import quat_from_rotvec


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
