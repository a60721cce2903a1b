"""How perceived motion enters the particles before physics: Algorithm 2's teleports, timed so that
the belief at time t is the scene at t, the spin of rolling balls, and let-goes in motion.

Flat functions on arrays, in place where they say so. K particles, M objects; positions in metres,
velocities ``(..., 6)`` linear (m/s) then angular (rad/s), quaternions ``(x, y, z, w)``.

* :func:`teleport_kinds`: which teleported objects keep a velocity (tracked moving along their
  support, or rolled off an edge and falling);
* :func:`place`: Alg. 2, put objects at their (timed) perception with noise, carrying their contents;
* :func:`rolling_spin` / :func:`roll_released`: balls spin as they roll without slipping;
* :func:`out_of_reach`: objects farther than a radius from every tracked hand;
* :func:`let_go_moving`: the importance move that lets a held object go in motion.
"""
from __future__ import annotations

import math

import numpy as np

from actions.modes import is_held
from physics.transforms import carry_pose, quat_from_rotvec, quat_multiply

from ..config import NoiseConfig

MOVING_MAX_VERTICAL_SPEED = 0.2
"""With ``moving_teleports``, only objects perceived moving along their support (vertical speed below
this, m/s) keep their velocity when teleported: a falling object's finite-difference velocity (over
a bounce, into a container) throws its particles off, and the paper's teleport at rest serves it well.
A falling object that was moving along its support at the previous update, horizontally faster than
this, rolled off an edge: it keeps its horizontal velocity and its particle's spin (a dropped
object's horizontal finite difference is mostly noise). Also the speed along a support above which a
held object counts as moving for :func:`let_go_moving`."""


def rolled_along(vel: np.ndarray) -> np.ndarray:
    """``(M,)``: velocities ``(M, 3)`` (m/s) horizontally faster, vertically slower than
    :data:`MOVING_MAX_VERTICAL_SPEED`: moving along a support."""
    return (np.linalg.norm(vel[:, :2], axis=1) > MOVING_MAX_VERTICAL_SPEED) & (
        np.abs(vel[:, 2]) < MOVING_MAX_VERTICAL_SPEED)


def teleport_kinds(tracked: np.ndarray, tick_vel: np.ndarray,
                   previous_tick_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Of the objects teleported while ``tracked (M,)`` (perceived at the previous update, detected
    now, not a first sighting), those ``moving`` along their support (vertical tick velocity below
    :data:`MOVING_MAX_VERTICAL_SPEED`) and those ``falling`` off an edge (falling now, moving along at
    the previous update): ``tick_vel``, ``previous_tick_vel`` ``(M, 3)`` m/s. Returns both ``(M,)``."""
    level = np.abs(tick_vel[:, 2]) < MOVING_MAX_VERTICAL_SPEED
    return tracked & level, tracked & ~level & rolled_along(previous_tick_vel)


def place(poses: np.ndarray, vel: np.ndarray, idx: np.ndarray, newly_known: np.ndarray, is_in: np.ndarray,
          positions: np.ndarray, orientations: np.ndarray, has_orientation: np.ndarray, perc_vel: np.ndarray,
          noise: NoiseConfig, rng: np.random.Generator, spinning: np.ndarray | None = None,
          held: np.ndarray | None = None, ball_radius: np.ndarray | None = None,
          vel_std: np.ndarray | None = None, gliding: np.ndarray | None = None,
          level: np.ndarray | None = None) -> np.ndarray:
    """Alg. 2, in place on ``poses (K, M, 7)`` and ``vel (K, M, 6)``: put objects ``idx`` at
    ``positions (M, 3)`` (their perception, or where it was at the update's start) plus perception
    noise per particle (``noise.position_std``; none where ``held (K, M)``: a held object goes to its
    target, and a noisy start would only give it a spurious velocity), at ``orientations (M, 4)``
    where ``has_orientation (M,)`` (noised by a quarter of ``noise.orientation_std``), with the
    perceived linear velocity ``perc_vel (M, 3+)``. The contents of each (``is_in (K, M, M)`` at the
    last update; not for ``newly_known (M,)`` objects) are carried rigidly, rotation included, and
    given the container's velocity, except in particles where the container is ``gliding (K, M)``
    (held, outside paper mode): it glides on to its target and what it carries keeps its own
    velocity (a ball in a box the hand starts moving lags and rolls to the back wall; given the
    box's velocity at every teleport, it would ride in the box as if glued). Paper mode puts a
    container and its contents at rest. Objects ``spinning (M,)`` (teleported in motion) get, per particle,
    horizontal velocity noise of standard deviation ``vel_std (M,)`` (m/s; the perceived velocity's
    standard error: a hidden object goes on with what its last detections allow, not with one
    velocity in every particle) and keep each particle's angular velocity, balls among them
    (``ball_radius (M,)``, NaN for other shapes) the spin of rolling at their velocity
    (:func:`rolling_spin`); the others have none. Objects ``level (M,)`` are moved horizontally only:
    each particle keeps its own height and orientation (what its support gives a resting object,
    rather than a noisy detection's, which would put it into what it rests on or under). Returns the
    position noise ``(K, len(idx), 3)`` m each particle's object got."""
    K = len(poses)
    new = poses[:, idx].copy()
    new[..., :3] = positions[idx]
    drawn = np.zeros((K, len(idx), 3))
    if noise.position_std > 0:
        drawn = rng.normal(0.0, noise.position_std, new[..., :3].shape)
        if held is not None:
            drawn[held[:, idx]] = 0.0
        new[..., :3] += drawn
    has_q = has_orientation[idx]
    new[:, has_q, 3:] = orientations[idx[has_q]]
    if noise.orientation_std > 0 and np.any(has_q):
        dq = quat_from_rotvec(rng.normal(0.0, noise.orientation_std / 4, (K, int(has_q.sum()), 3)))
        new[:, has_q, 3:] = quat_multiply(dq, new[:, has_q, 3:])
    if level is not None and np.any(level[idx]):
        flat = level[idx]
        new[:, flat, 2], new[:, flat, 3:] = poses[:, idx[flat], 2], poses[:, idx[flat], 3:]
        drawn[:, flat, 2] = 0.0
    placed = np.zeros(poses.shape[1], dtype=bool)
    placed[idx] = True
    for j, b in enumerate(np.asarray(idx).tolist()):  # one container at a time, all particles at once
        if newly_known[b]:
            continue
        kk, aa = np.nonzero(is_in[:, :, b] & ~placed)  # its contents not placed themselves
        if len(kk):
            poses[kk, aa] = carry_pose(poses[kk, aa], poses[kk, b], new[kk, j])
            free = np.ones(len(kk), dtype=bool) if gliding is None else ~gliding[kk, b]
            # a held container glides on: what it carries keeps its own velocity (it lags, rolls)
            vel[kk[free], aa[free], :3] = perc_vel[b, :3]
    poses[:, idx] = new
    spin = vel[:, idx, 3:].copy()
    vel[:, idx] = 0.0
    vel[:, idx, :3] = perc_vel[idx, :3]
    if spinning is not None:
        keep = spinning[idx]
        if vel_std is not None and np.any(vel_std[idx[keep]] > 0):
            vel[:, idx[keep], :2] = velocity_draws(perc_vel, vel_std, idx[keep], K, rng)
        vel[:, idx[keep], 3:] = spin[:, keep]
        if ball_radius is not None:
            rolling_spin(vel, idx[keep], ball_radius)
    return drawn


def velocity_draws(perc_vel: np.ndarray, vel_std: np.ndarray, idx: np.ndarray, K: int,
                   rng: np.random.Generator) -> np.ndarray:
    """Horizontal velocities ``(K, len(idx), 2)`` (m/s) of objects ``idx`` per particle: their
    perceived velocity ``perc_vel (M, 2+)`` plus normal noise of its standard error ``vel_std (M,)``
    (m/s) per axis. One standard normal draw per entry."""
    idx = np.asarray(idx, dtype=int)
    return perc_vel[idx, :2][None] + rng.normal(0.0, 1.0, (K, len(idx), 2)) * vel_std[idx][None, :, None]


def rolling_spin(vel: np.ndarray, idx: np.ndarray, ball_radius: np.ndarray, rows: np.ndarray | None = None) -> None:
    """In place on ``vel (K, M, 6)``: the balls among objects ``idx`` (finite ``ball_radius (M,)`` m;
    in the particles ``rows (K,)`` bool, default all) spin as they roll without slipping at their
    horizontal velocity, ``w = z x v / r``: a ball given a velocity with another particle's spin, or
    none (just let go from a hand), would otherwise slide and slow down for a while."""
    idx = np.asarray(idx, dtype=int)
    idx = idx[np.isfinite(ball_radius[idx])]
    if len(idx) == 0:
        return
    rows = np.ones(len(vel), dtype=bool) if rows is None else rows
    v = vel[:, idx, :3]
    w = np.stack([-v[..., 1], v[..., 0], np.zeros_like(v[..., 0])], axis=-1) / ball_radius[idx][None, :, None]
    vel[:, idx, 3:] = np.where(rows[:, None, None], w, vel[:, idx, 3:])


def roll_released(vel: np.ndarray, released: np.ndarray, ball_radius: np.ndarray) -> None:
    """In place on ``vel (K, M, 6)``: balls let go now (``released (K, M)``) roll at the velocity
    the hand gave them (:func:`rolling_spin`; held, they did not spin). Pass only those on a support
    or seen rolling along one just before (off an edge): one dropped from the air has a small
    horizontal velocity that is mostly noise, which rolling would keep."""
    for m in np.flatnonzero(released.any(axis=0)):
        rolling_spin(vel, np.array([m]), ball_radius, released[:, m])


def out_of_reach(positions: np.ndarray, hands: dict, objects: np.ndarray, radius: float) -> np.ndarray | None:
    """Objects ``(M,)`` among ``objects (M,)`` bool whose ``positions (M, 3)`` m lie farther than
    ``radius`` m from every hand in ``hands`` (name -> position ``(3,)``); None when no hand is given."""
    if not hands:
        return None
    pts = np.array([np.asarray(h, float) for h in hands.values()])  # (H, 3)
    d = np.linalg.norm(positions[:, None, :3] - pts[None], axis=-1).min(axis=1)
    return np.asarray(objects, dtype=bool) & (d > radius)


def let_go_moving(modes: np.ndarray, supported: np.ndarray, candidates: np.ndarray, tick_vel: np.ndarray,
                  q: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Let-goes in motion: of the ``candidates (M,)`` (seen in this update with no tracked hand within
    reach) moving along their support (tick velocity ``(M, 3)`` m/s, see :data:`MOVING_MAX_VERTICAL_SPEED`),
    those held and ``supported (K, M)`` in a particle (``modes (K, M)``) are let go there with
    probability ``q``. Returns the let-goes ``(K, M)`` and their importance weights ``(K,)``: ``-log q``
    per let-go and ``-log(1 - q)`` per candidate kept, so that the switch's own prior (``place``,
    charged by the mode-switch term) is what weighs. One uniform draw per entry when there is a
    candidate; none, and nothing let go, when ``q`` is 0."""
    K, M = modes.shape
    cand_m = np.asarray(candidates, dtype=bool) & rolled_along(tick_vel)
    if q <= 0 or not np.any(cand_m):
        return np.zeros((K, M), dtype=bool), np.zeros(K)
    cand = is_held(modes) & supported & cand_m[None, :]
    let = cand & (rng.random((K, M)) < q)
    kept = cand & ~let
    logw = -math.log(q) * let.sum(axis=1) - (math.log1p(-q) if q < 1 else 0.0) * kept.sum(axis=1)
    return let, logw


def drop_heights(aabbs: np.ndarray, kk: np.ndarray, mm: np.ndarray, lift: np.ndarray, floor: bool) -> np.ndarray:
    """How far objects ``mm`` of particles ``kk`` (index arrays ``(N,)``) fall from ``lift (N,)`` (m)
    above their bottoms in ``aabbs (K, M, 2, 3)`` to the highest top under their footprints: of the
    other objects whose boxes overlap theirs horizontally and whose tops are under the middle of
    their height (an object held into a table top, a resting contact, still has the table under
    it), or the floor at 0 (``floor``; else nothing under: inf). ``(N,)`` m, at least 0."""
    box = aabbs[kk, mm]  # (N, 2, 3)
    bottom = box[:, 0, 2] + lift
    middle = 0.5 * (box[:, 0, 2] + box[:, 1, 2]) + lift
    others = aabbs[kk]  # (N, M, 2, 3)
    over = ((others[:, :, 0, 0] < box[:, None, 1, 0]) & (others[:, :, 1, 0] > box[:, None, 0, 0])
            & (others[:, :, 0, 1] < box[:, None, 1, 1]) & (others[:, :, 1, 1] > box[:, None, 0, 1]))
    tops = others[:, :, 1, 2]
    with np.errstate(invalid="ignore"):
        under = over & (tops <= middle[:, None])
    under[np.arange(len(kk)), mm] = False
    top = np.max(np.where(under, tops, -np.inf), axis=1)
    if floor:
        top = np.maximum(top, 0.0)
    return np.maximum(bottom - top, 0.0)
