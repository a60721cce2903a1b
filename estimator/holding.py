"""What held objects do in the scene model: let go when they stop being perceived, and follow their
hand while unseen. Array functions over K particles and M objects (metres, seconds); randomness from
the ``numpy.random.Generator`` passed in.
"""
from __future__ import annotations

import math

import numpy as np

from actions.modes import FREE, HELD, ModePriors, switch_events

from .config import NoiseConfig
from .held import hand_offset_walk
from .observations import Frame
from .perception_memory import PerceptionMemory


def release_on_loss(modes: np.ndarray, perceived: np.ndarray, supported: np.ndarray, rng: np.random.Generator,
                    memory: PerceptionMemory, priors: ModePriors,
                    tracked: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Releases of held objects that are not perceived (``modes (K, M)`` int8, ``perceived (M,)``).

    With probability ``release_on_loss`` when they were perceived at the last update; for the objects
    whose hand is tracked (``tracked (M,)``) ``release_on_loss_carried`` when the hand has moved more
    than ``carry_distance`` since the object was last seen (:meth:`PerceptionMemory.hand_travel`), else
    ``release_on_loss_still``; ``release`` per update after (not while the tracked hand has carried
    the object more than ``carry_distance`` since it was seen). Returns the new modes ``(K, M)`` and
    the event codes of the switches ``(K, M)`` (``supported (K, M)``: Place or Release)."""
    K, M = modes.shape
    new = modes.copy()
    lost = memory.perceived_prev & ~perceived
    u = rng.random((K, M))
    held_unseen = (new == HELD) & ~perceived[None, :]
    on_loss = np.full(M, priors.release_on_loss)
    later = np.full(M, priors.release)
    if tracked is not None and np.any(tracked):
        tracked = np.asarray(tracked, dtype=bool)
        carried = memory.hand_travel() > priors.carry_distance  # NaN (no hand): False
        on_loss[tracked & carried] = priors.release_on_loss_carried
        on_loss[tracked & ~carried] = priors.release_on_loss_still
        later[tracked & carried] = 0.0  # what a moving hand carries, it keeps
    p_rel = np.where(lost[None, :], on_loss[None, :], later[None, :])
    new[held_unseen & (u < p_rel)] = FREE
    return new, switch_events(modes, new, supported)


def held_targets(frame: Frame, poses: np.ndarray, modes: np.ndarray, detected: np.ndarray, perceived: np.ndarray,
                 dt: float, rng: np.random.Generator, hold_error: np.ndarray, memory: PerceptionMemory,
                 noise: NoiseConfig, moving_teleports: bool,
                 teleported: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Targets ``(K, M, 7)``, target velocities ``(K, M, 6)`` and offset errors ``(K, M, 3)``.

    Perceived objects at their perception (no noise: it would shake what a held object carries), with
    their perceived velocity (with ``moving_teleports``, only those ``teleported (M,)`` now; the
    divergence test then carries the target on at that velocity, see
    :func:`~estimator.propagate.propagate_batch`); held objects not detected in this update follow the
    hand that held them when last detected, if it is tracked, at its offset then plus each particle's
    error (``hold_error (K, M, 3)`` before, walked by :func:`~estimator.held.hand_offset_walk`), else
    stay where they were perceived (while perceived) or where the particle has them, drifting by
    ``held_drift_std`` (m per sqrt(s)) when not perceived. Others: their pose in ``poses (K, M, 7)``."""
    K, M = modes.shape
    new_error = np.zeros_like(hold_error)
    target = poses.copy()
    target_vel = np.zeros((K, M, 6))
    pidx = np.flatnonzero(perceived)
    if len(pidx):
        target[:, pidx, :3] = memory.last_pose[pidx, :3]
        has_q = memory.last_has_orientation[pidx]
        target[:, pidx[has_q], 3:] = memory.last_pose[pidx[has_q], 3:]
        # with moving_teleports the divergence test carries a target on at its velocity: only
        # objects teleported in motion (placed at their detection now) have one
        with_vel = perceived
        if moving_teleports:
            with_vel = perceived & (np.zeros(M, bool) if teleported is None else teleported)
        vidx = np.flatnonzero(with_vel)
        target_vel[:, vidx, :3] = memory.perc_vel[vidx, :3]
    held = (modes == HELD) & ~detected[None, :]
    for m in np.flatnonzero(held.any(axis=0)):
        rows = held[:, m]
        hand = memory.hand_target(frame, m)
        if hand is not None:
            new_error[rows, m] = hand_offset_walk(hold_error[rows, m], dt, noise.held_offset_std,
                                                  noise.held_offset_time, rng)
            target[rows, m, :3] = hand + new_error[rows, m]
        elif not perceived[m] and noise.held_drift_std > 0:
            target[rows, m, :3] += rng.normal(0.0, noise.held_drift_std * math.sqrt(dt), (int(rows.sum()), 3))
    return target, target_vel, new_error
