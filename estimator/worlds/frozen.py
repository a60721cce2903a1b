"""Objects that an update cannot reach: taken out of collision detection while it steps.

A sleeping body still costs Bullet every step: its broadphase pairs with the table and its
neighbours are found and filtered again, although no contact of a sleeping pair is solved (a body
asleep costs nearly what an awake one at rest does; objects at rest are most of the stepping time
on the cluttered scenes). Out of collision detection (collision group 0) it costs nothing. That
is exact only for an object that nothing awake can touch during the update, because no contact
with it can then be made. This module decides which objects are such, from the particles' arrays
and a bound on how far anything can move in one update of ``T`` seconds:

* an object *awake* at the update's start (loaded, held, pushed out of penetration, moving, or
  tested against a perception it may be set to) stays in the box that holds its own box (its
  body-frame box at a pose) where it is, where its velocity takes it in ``T`` and at its target
  (held objects glide there; a tested one may be set there), widened by how far its spin or its
  glide's turn moves its points and by ``g T^2 / 2 + margin`` (a fall, pushes out of
  penetration, the contact distance). An object held from the update's start is set on its glide
  at every step and cannot fall: its box is widened by ``margin`` only (a mug carried 5 cm beside
  a box does not reach it);
* an object at rest (its box exact: its body-frame box at its pose) that comes within that of
  something awake may be hit. Its points then move at most ``4 v T + g T^2 / 2 + margin``, with
  ``v`` the fastest point of anything awake in the particle (speed plus spin times bounding
  radius, or the speed of a glide): an object at rest that is hit leaves with its contact point at
  most twice as fast as what hit it, and its other points, turning, at most about twice that
  again. Whatever comes within that reach of its box may be hit in turn, until nothing more is
  reached.

What is left is *frozen* for the update: :func:`~estimator.worlds.propagate.propagate_batch` takes
it out of collision detection after loading, and it stays out
(:attr:`~estimator.worlds.batch.ParticleWorld.frozen`) until an update may reach it or rays are to
be cast in its world (:meth:`~estimator.worlds.batch.ParticleWorld.thaw`: a body out of collision
detection is invisible to rays). Bullet forgets the contacts of a body it
takes out of collision, and a sleeping pair does not make them again: the caller must not rely on
a frozen object's old contacts (:attr:`~estimator.worlds.batch.ParticleWorld.contactless`).
"""
from __future__ import annotations

import numpy as np

from physics.transforms import quat_angle, quat_to_matrix
from physics.visibility import local_box
from physics.world import World

FREEZE_MARGIN = 0.02
"""m: added to the reach of an update: what pushing an object out of penetration and the
regularisation jitter may move it by, and the contact distance of Bullet's pairs."""


def local_boxes(world: World) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame boxes about each object's centre of mass: centres ``(M, 3)`` and half-extents
    ``(M, 3)`` (m), exact (each object's bounding box with its centre-of-mass frame turned to
    the identity, :func:`physics.visibility.local_box`); zeros for static objects, never frozen.
    Each object is turned and set back (a float round trip): measure a world before it runs (the
    shards do so when they build their worlds). A box read at the pose an object happens to hold
    would be larger than the object by up to twice for a turned one (a mug's yawed 45 degrees:
    20 cm across for its 9 cm), and every object within that of something moving kept awake."""
    M = world.num_objects
    centre, half = np.zeros((M, 3)), np.zeros((M, 3))
    ident = np.zeros((1, M, 7))
    ident[..., 6] = 1.0
    inertial = world.com_frame(ident)[0][0]  # (M, 7): each centre-of-mass frame in its link frame
    for i in (int(i) for i in world.dynamic_indices):
        c_link, h_link = local_box(world, i)  # link frame turned to the identity
        rot_t = quat_to_matrix(inertial[i, 3:]).T  # link -> centre-of-mass frame
        centre[i] = rot_t @ (c_link - inertial[i, :3])
        half[i] = np.abs(rot_t) @ h_link
    return centre, half


def _within(lo: np.ndarray, hi: np.ndarray, lo2: np.ndarray, hi2: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """``(K, M, M)`` bool: whether boxes ``lo, hi (K, M, 3)`` (axis 1) and ``lo2, hi2 (K, M, 3)``
    (axis 2) come closer than ``dist`` (m): ``(K,)``, one per row, or ``(K, M)``, one per box of
    axis 2."""
    total = np.zeros(lo.shape[:2] + lo2.shape[1:2])
    for a in range(3):  # one axis at a time: contiguous (K, M, M) arrays
        lo_a, hi_a, lo2_a, hi2_a = (np.ascontiguousarray(x[..., a]) for x in (lo, hi, lo2, hi2))
        sep = np.maximum(lo_a[:, :, None] - hi2_a[:, None], lo2_a[:, None] - hi_a[:, :, None])
        np.maximum(sep, 0.0, out=sep)
        total += sep * sep
    dist = np.asarray(dist)
    return total < (np.square(dist)[:, None, None] if dist.ndim == 1 else np.square(dist)[:, None, :])


def _world_boxes(poses: np.ndarray, boxes: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes ``lo, hi (..., M, 3)`` of the body-frame ``boxes`` at centre-of-mass
    ``poses (..., M, 7)``."""
    rot = quat_to_matrix(poses[..., 3:])
    mid = poses[..., :3] + np.einsum("...mij,mj->...mi", rot, boxes[0])
    ext = np.einsum("...mij,mj->...mi", np.abs(rot), boxes[1])
    return mid - ext, mid + ext


def unreachable(com_poses: np.ndarray, shift: np.ndarray, targets: np.ndarray, spread: np.ndarray,
                speeds: np.ndarray, boxes: tuple[np.ndarray, np.ndarray], resting: np.ndarray, awake: np.ndarray,
                horizon: float, gravity: float = 9.81, margin: float = FREEZE_MARGIN,
                gliding: np.ndarray | None = None) -> np.ndarray:
    """Which resting objects no awake object can touch during an update (see the module docstring).

    com_poses ``(K, M, 7)``: centre-of-mass poses at the update's start (m, quaternions x, y, z, w).
    shift ``(K, M, 3)`` (m): where each awake object's velocity takes it in ``horizon``. targets
    ``(K, M, 7)``: the centre-of-mass pose it may be set or glide to (its own pose if none). spread
    ``(K, M)`` (m): how far its points may move by turning. speeds ``(K, M)`` (m/s): the fastest point of each awake
    object. boxes: :func:`local_boxes`. resting ``(K, M)`` bool: the candidates (asleep, not moved,
    not able to switch mode). awake ``(K, M)`` bool: everything that moves or may (static objects
    and candidates excluded). horizon (s): the update's length. gliding ``(K, M)`` bool (default
    none): the awake objects set on a path at every step (held from the update's start), which
    cannot fall. Returns ``(K, M)`` bool, a subset of ``resting``."""
    frozen = resting & ~awake
    rows = np.flatnonzero(frozen.any(axis=1) & awake.any(axis=1))  # particles where anything may be reached
    if len(rows) == 0:
        return frozen
    shift, spread, speeds, awake = shift[rows], spread[rows], speeds[rows], awake[rows]
    fall = 0.5 * abs(gravity) * horizon ** 2 + margin
    near = np.full(awake.shape, fall) if gliding is None else np.where(gliding[rows], margin, fall)
    lo_r, hi_r = _world_boxes(com_poses[rows], boxes)  # (R, M, 3) each
    lo, hi = sweeps(boxes, com_poses[rows], shift, targets[rows], spread)
    vmax = np.where(awake, speeds, 0.0).max(axis=1, initial=0.0)  # (R,)
    reach = 4.0 * vmax * horizon + fall
    # candidate (axis 1) within reach of an awake object's sweep, or of a hit one's box (axis 2)
    sub = frozen[rows]
    hit = (_within(lo_r, hi_r, lo, hi, near) & awake[:, None, :]).any(axis=2) & sub
    if hit.any():
        pushed = _within(lo_r, hi_r, lo_r, hi_r, reach)
    while hit.any():
        sub &= ~hit
        hit = (pushed & hit[:, None, :]).any(axis=2) & sub
    frozen[rows] = sub
    return frozen


def alone(lo: np.ndarray, hi: np.ndarray, gliding: np.ndarray, dyn: np.ndarray, statics: np.ndarray,
          floor: np.ndarray | None, margin: float = FREEZE_MARGIN) -> np.ndarray:
    """``(K, M)`` bool: which of the ``gliding (K, M)`` objects (held from the update's start) come
    within ``margin`` (m) of nothing during it: of no other dynamic object (``dyn (M,)`` bool),
    of no static one and not of the floor. ``lo, hi (K, M, 3)``: where each dynamic object may be
    during the update (:func:`unreachable`'s sweeps: a gliding object's, widened by how far its
    turn moves its points; another's, by its fall and spin, whether awake or not). ``statics (K,
    S, 2, 3)``: the static objects' boxes; ``floor (K,)``: the floor's height, or None without one
    (all in the client frame, m). Nothing can touch such an object and it can touch nothing: it
    need not be set on its glide at every step, only placed at its end."""
    out = gliding & dyn
    rows = np.flatnonzero(out.any(axis=1))
    if len(rows) == 0:
        return out
    lo_r, hi_r = lo[rows], hi[rows]
    near = _within(lo_r, hi_r, lo_r, hi_r, np.full(len(rows), margin)) & dyn[None, None, :]
    near[:, np.arange(lo.shape[1]), np.arange(lo.shape[1])] = False  # (not itself)
    sub = out[rows] & ~near.any(axis=2)
    if statics.shape[1]:
        sub &= ~_within(lo_r, hi_r, statics[rows, :, 0], statics[rows, :, 1], np.full(len(rows), margin)).any(axis=2)
    if floor is not None:
        sub &= lo_r[..., 2] > floor[rows, None] + margin
    out[rows] = sub
    return out


def sweeps(boxes: tuple[np.ndarray, np.ndarray], com_p: np.ndarray, shift: np.ndarray, targets: np.ndarray,
           spread: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (K, M, 3)`` that hold each object's box (:func:`local_boxes`) at its
    centre-of-mass pose ``com_p (K, M, 7)``, moved by ``shift (K, M, 3)`` and at ``targets (K, M,
    7)``, widened by ``spread (K, M)`` (m)."""
    lo_r, hi_r = _world_boxes(com_p, boxes)
    lo_t, hi_t = _world_boxes(targets, boxes)
    lo = np.minimum(np.minimum(lo_r, lo_r + shift), lo_t) - spread[..., None]
    hi = np.maximum(np.maximum(hi_r, hi_r + shift), hi_t) + spread[..., None]
    return lo, hi


def to_freeze(boxes: tuple[np.ndarray, np.ndarray], com_p: np.ndarray, com_v: np.ndarray, target_com: np.ndarray,
              tvel: np.ndarray, target_orn: np.ndarray, checked: np.ndarray, held: np.ndarray, moved: np.ndarray,
              dyn: np.ndarray, horizon: float, d_sim_perc: float, gravity: float,
              statics: np.ndarray | None = None, floor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(K, M)`` bool: the objects to freeze for an update of ``horizon`` seconds
    (:func:`unreachable`), from the client-frame centre-of-mass state
    ``com_p (K, M, 7)``, ``com_v (K, M, 6)`` and the tests' targets at the update's start
    ``target_com (K, M, 3)`` moving at ``tvel (K, M, 3)``. A candidate is asleep: exactly zero
    velocity, and not ``moved`` (loaded, held, pushed out of penetration: ``moved`` must also hold
    what a world holds but never stepped, which reads zero velocity awake, and what it held at the
    last update's end and is let go now, which reads its still hand's zero velocity awake, perhaps
    in the air; a settled load is a candidate, put to sleep if frozen); not held; and if tested, one
    that cannot diverge while it stays still (its target fixed and nearer than ``d_sim_perc``). Held
    and tested objects may go to their targets (orientations ``target_orn (K, M, 4)``); ``dyn (M,)``
    bool: the dynamic objects.
    Returns that and, given the static objects' boxes ``statics (K, S, 2, 3)`` and the floor's
    height ``floor (K,)`` (None: no floor), the held objects that are :func:`alone` (else none)."""
    centres = com_p[..., :3]
    goes = (checked | held)[..., None]
    targets = np.where(goes, np.concatenate([target_com + tvel * horizon, target_orn], axis=-1), com_p)
    still = ~np.any(com_v != 0.0, axis=-1)
    steady = ~checked | ((np.linalg.norm(centres - target_com, axis=-1) < d_sim_perc) & ~np.any(tvel != 0.0, axis=-1))
    resting = dyn & still & ~moved & ~held & steady
    radius = np.linalg.norm(np.abs(boxes[0]) + boxes[1], axis=-1)  # (M,)
    spin = np.linalg.norm(com_v[..., 3:], axis=-1) * radius
    turn = np.where(held, np.minimum(quat_angle(com_p[..., 3:], target_orn), 2.0) * radius, 0.0)  # a glide's turn
    speeds = np.maximum(np.linalg.norm(com_v[..., :3], axis=-1) + spin,
                        np.linalg.norm(targets[..., :3] - centres, axis=-1) / horizon + turn / horizon)
    # a glide's point strays from the hull of its two end boxes by at most twice its turn: once
    # from the straight path of its start orientation, once from the end box at that orientation
    shift, spread = com_v[..., :3] * horizon, np.minimum(spin * horizon, 2.0 * radius) + 2.0 * turn
    frozen = unreachable(com_p, shift, targets, spread, speeds, boxes, resting, dyn & ~resting, horizon, gravity,
                         gliding=held)
    lonely = np.zeros_like(frozen)
    if statics is not None and held.any():
        # where the others may be: their sweeps, widened by a fall and by what a hit from anything
        # awake and not held may give them (the held ones alone hit nothing)
        vmax = np.where(dyn & ~resting & ~held, speeds, 0.0).max(axis=1, initial=0.0)  # (K,)
        reach = np.where(held, 0.0, 4.0 * vmax[:, None] * horizon + 0.5 * abs(gravity) * horizon ** 2)
        lo, hi = sweeps(boxes, com_p, shift, targets, spread + reach)
        lonely = alone(lo, hi, held, dyn, statics, floor)
    return frozen, lonely
