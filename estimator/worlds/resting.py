"""Resting objects in the particle worlds: when they sleep, and how a sleeping one is restarted.

With :attr:`~physics.world.PhysicsSettings.sleeping`, a free object at rest at both ends of an
update is put to sleep (stepping skips it until something touches it, it is woken or reset; see
:mod:`physics.sleep`), and one loaded with a velocity while asleep is given that velocity again
after the first step (Bullet clears a woken body's velocity in it). Used by
:func:`~estimator.worlds.propagate.propagate_batch`; the thresholds also by the scene model (an object the
fusion of detections nudges while slower than them is set at rest and loaded asleep).
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from physics.sleep import sleep
from physics.transforms import quat_angle, quat_from_rotvec, quat_multiply
from physics.world import World

REST_SPEED = 0.005
"""m/s: with sleeping enabled, a free object moving slower than this (and turning slower than
:data:`REST_SPIN`) at the start and at the end of an update, and not moved by the update's loads, is
put to sleep: stepping skips it until something touches it or it is reset."""
REST_SPIN = 0.05
"""rad/s: see :data:`REST_SPEED`."""
PROBE_STEPS = 4
"""With ``sleep_loads``: objects at rest that an update loaded or woke (in a world never stepped,
all of them) are probed after this many steps, and those then slower than the update's end test
scaled to these steps (:data:`~estimator.worlds.resting.REST_SPEED` and
:data:`~estimator.worlds.resting.REST_SPIN` times ``PROBE_STEPS / n_steps``: at a constant
acceleration, still at rest by that test at the update's end) are put to sleep then, not after
the update; those slower than the test itself are probed again as many steps later, and sleep if
they have not sped up (:func:`sleep_settling`). Bullet wakes again any of them whose island
something awake moves. Updates of fewer than three times this many steps are not probed."""

SETTLED_REACH = 0.03
"""m: a settled object loaded asleep (:class:`~estimator.worlds.batch.StepInput` ``settled``) is woken when an object of its
particle that the update moves ends within this distance of it (boxes): three times the largest
regularisation jitter, so that an object whose support was jittered away does not float."""


def at_rest(before: np.ndarray, after: np.ndarray, dt: float) -> bool:
    """Whether poses ``(D, 7)`` (link frames, quaternions x, y, z, w) taken ``dt`` seconds apart
    moved slower than :data:`REST_SPEED` and turned slower than :data:`REST_SPIN` on average (the
    ground truth's settling and the prior at rest, :mod:`estimator.model.prior`, test rest so)."""
    speed = np.linalg.norm(after[:, :3] - before[:, :3], axis=1) / dt
    spin = quat_angle(after[:, 3:], before[:, 3:]) / dt
    return bool(np.all(speed < REST_SPEED) and np.all(spin < REST_SPIN))


def slow(vel: np.ndarray) -> np.ndarray:
    """``(...)`` bool: velocities ``(..., 6)`` slower than :data:`REST_SPEED` and turning slower than
    :data:`REST_SPIN`: at rest, for sleeping."""
    return (np.linalg.norm(vel[..., :3], axis=-1) < REST_SPEED) & (np.linalg.norm(vel[..., 3:], axis=-1) < REST_SPIN)


def sleep_resting(pws: list, candidates: np.ndarray, vel_in: np.ndarray,
                  vel_out: np.ndarray) -> None:
    """Put to sleep the ``candidates (K, M)`` at rest at both ends of the update (velocities
    ``(K, M, 6)``, :func:`slow`) that are still awake (a sleeping body reads back exactly zero
    velocity)."""
    rest = candidates & slow(vel_in) & slow(vel_out) & np.any(vel_out != 0.0, axis=-1)
    for k in np.flatnonzero(rest.any(axis=1)).tolist():
        sleep(pws[k].world, np.flatnonzero(rest[k]).tolist())


def sleep_still(client: int, uids: list[int], scale: float, count: list[int]) -> list[tuple[int, float, float]]:
    """Put to sleep the bodies ``uids`` of pybullet client ``client`` moving slower than
    :data:`REST_SPEED` and turning slower than :data:`REST_SPIN`, both times ``scale`` (the hot
    path: direct pybullet calls); their number is added to ``count[0]``. Returns the others that are
    slower than the thresholds themselves, as ``(body id, speed^2, spin^2)``, for
    :func:`sleep_settling`."""
    change, asleep = pb.changeDynamics, pb.ACTIVATION_STATE_SLEEP
    v_max, w_max = (REST_SPEED * scale) ** 2, (REST_SPIN * scale) ** 2
    v_rest, w_rest = REST_SPEED ** 2, REST_SPIN ** 2
    slow = []
    for uid in uids:
        v2, w2 = _squared_speeds(client, uid)
        if v2 < v_max and w2 < w_max:
            change(uid, -1, activationState=asleep, physicsClientId=client)
            count[0] += 1
        elif v2 < v_rest and w2 < w_rest:
            slow.append((uid, v2, w2))
    return slow


def sleep_settling(client: int, slow: list[tuple[int, float, float]], count: list[int]) -> None:
    """Put to sleep the bodies of ``slow`` (:func:`sleep_still`'s answer, some steps ago) that have
    not sped up since, in speed nor in spin: loaded at rest, a body out of balance (tipping, sliding,
    unsupported) speeds up from the start, while one in balance only rings down from its contacts
    being made afresh (a mug loaded on the table reads 1.4 mm/s four steps later, less after
    eight). Their number is added to ``count[0]``."""
    change, asleep = pb.changeDynamics, pb.ACTIVATION_STATE_SLEEP
    for uid, v2_before, w2_before in slow:
        v2, w2 = _squared_speeds(client, uid)
        if v2 <= v2_before and w2 <= w2_before:
            change(uid, -1, activationState=asleep, physicsClientId=client)
            count[0] += 1


def _squared_speeds(client: int, uid: int) -> tuple[float, float]:
    """Squared speed (m^2/s^2) and squared spin (rad^2/s^2) of body ``uid`` of pybullet client ``client``."""
    v, w = pb.getBaseVelocity(uid, physicsClientId=client)
    return v[0] * v[0] + v[1] * v[1] + v[2] * v[2], w[0] * w[0] + w[1] * w[1] + w[2] * w[2]


def restart_after_wake(w: World, rows: list[int], com_p: np.ndarray, com_v: np.ndarray, dt: float,
                       gravity: float) -> list[tuple]:
    """For objects ``rows`` loaded with a velocity while asleep (Bullet clears a woken body's velocity
    in its first step): the state to give them after that step, that of one free step from the
    loaded centre-of-mass state ``com_p (M, 7)`` (client frame), ``com_v (M, 6)`` (semi-implicit
    Euler, as Bullet integrates), as ``[(body id, position, orientation, linear, angular)]``."""
    if not rows:
        return []
    v = com_v[rows].copy()
    v[:, 2] += gravity * dt
    pos = com_p[rows, :3] + v[:, :3] * dt
    orn = quat_multiply(quat_from_rotvec(v[:, 3:] * dt), com_p[rows, 3:])
    return [(w.uids[i], pos[j].tolist(), orn[j].tolist(), v[j, :3].tolist(), v[j, 3:].tolist())
            for j, i in enumerate(rows)]


def sleep_as_loaded(w: World, rows: list[int], com_p: np.ndarray) -> list[tuple]:
    """Put objects ``rows`` to sleep where they were loaded, centre-of-mass poses ``com_p (M, 7)``
    (client frame): at rest as surely as if a world had made them so (a settled load; in a world
    that never stepped, whose bodies are all awake, one the model placed at rest,
    :func:`~estimator.model.regularisation.placed_at_rest`). Bullet still moves a body put to sleep
    in its next step (out of collision, a fall of g dt^2): returns the state to give them after that
    step, as :func:`restart_after_wake` does (nothing for no rows)."""
    sleep(w, rows)
    return [(w.uids[i], com_p[i, :3].tolist(), com_p[i, 3:].tolist(), [0.0] * 3, [0.0] * 3) for i in rows]
