"""What one run of the particle worlds takes and gives (plain arrays, so that worker processes exchange
only numpy data), and a particle slot's world (:class:`ParticleWorld`). K particles, M objects;
positions in metres, quaternions ``(x, y, z, w)``, velocities in m/s and rad/s. The run itself is
:func:`~estimator.worlds.propagate.propagate_batch`.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import chain

import numpy as np

from physics.world import World

from .frozen import local_boxes

PARAM_NAMES = ("lateral_friction", "rolling_friction", "spinning_friction", "restitution", "mass")
"""Columns of the per-object physical parameter arrays ``(..., M, 5)`` (mass in kg)."""


@dataclass
class StepInput:
    """Inputs of one particle's update; M objects.

    poses ``(M, 7)``, velocities ``(M, 6)``: state to start from. params ``(M, 5)`` (see
    :data:`PARAM_NAMES`). modes ``(M,)`` int8. check ``(M,)`` bool: FREE objects to test against
    ``target``. target ``(M, 7)`` / target_vel ``(M, 6)``: perceived (or held) pose and velocity.
    contents ``(M, M)`` bool: ``contents[a, b]`` = a is in b (a moves with b when b is overridden).
    reset ``(M,)`` bool or None: objects whose pose and velocity must be loaded into the world (the
    others already hold the state the world left them in); None loads all.
    settled ``(M,)`` bool or None: objects whose loaded state is one a world produced at rest (zero
    velocity) and nothing changed since (a resampled particle's), or that were only moved along
    their support by the fusion of detections: with sleeping on, they are loaded asleep, not woken
    (what the particle's other objects do may still wake them).
    depenetrate ``(M,)`` bool: objects just placed with perturbed poses, to be pushed out of anything
    they interpenetrate before stepping (a perturbation must not start a box inside the table).
    """

    poses: np.ndarray
    velocities: np.ndarray
    params: np.ndarray
    modes: np.ndarray
    check: np.ndarray
    target: np.ndarray
    target_vel: np.ndarray
    contents: np.ndarray
    depenetrate: np.ndarray
    reset: np.ndarray | None = None
    settled: np.ndarray | None = None


@dataclass
class StepOutput:
    """Result of one particle's update: poses ``(M, 7)``, velocities ``(M, 6)``, modes ``(M,)``,
    max_divergence ``(M,)`` (m, over the steps, for checked objects; 0 otherwise), aabbs ``(M, 2, 3)``,
    finite: False if the simulation produced NaN or a runaway velocity (bool; ``(K,)`` in a batch)."""

    poses: np.ndarray
    velocities: np.ndarray
    modes: np.ndarray
    max_divergence: np.ndarray
    aabbs: np.ndarray
    finite: bool | np.ndarray


@dataclass
class BatchInput(StepInput):
    """Inputs for K particles: the fields of :class:`StepInput` with a leading K axis, plus
    ``vis_query (M,)`` bool: objects whose visibility to the camera is wanted after the update
    (None: none)."""

    vis_query: np.ndarray | None = None


PER_PARTICLE = ("poses", "velocities", "params", "modes", "check", "target", "target_vel", "contents",
                "depenetrate", "reset", "settled")
"""The fields of :class:`BatchInput` with a leading particle axis."""


@dataclass
class BatchOutput(StepOutput):
    """Outputs for K particles: the fields of :class:`StepOutput` with a leading K axis (``finite
    (K,)``), plus ``visible (K, M)``: fraction of each object's sample points seen by the camera (0
    where not queried)."""

    visible: np.ndarray | None = None


class ParticleWorld:
    """A persistent world for one particle slot, remembering the parameters last applied.

    ``frozen``: objects out of collision detection because nothing could reach them at the last
    update (:mod:`~estimator.worlds.frozen`); :meth:`thaw` puts them back (before any ray test).
    ``contactless``: objects an update took out of collision (:mod:`~estimator.worlds.frozen`) and
    that have not been awake since: Bullet has forgotten their contacts. ``boxes``: the objects'
    body-frame boxes (:func:`~estimator.worlds.frozen.local_boxes`), as given (the same for every
    copy of a scene) or measured in ``world`` now (turning its objects: build it before its run)."""

    def __init__(self, world: World, boxes: tuple[np.ndarray, np.ndarray] | None = None):
        self.world = world
        self.dynamic = [int(i) for i in world.dynamic_indices]
        self.contactless: set[int] = set()
        self.frozen: list[int] = []
        self.stepped = False  # stepped since its last loads (else what it holds is awake at zero velocity)
        # (M,) bool: objects held at the end of its last update: one let go since reads its hand's
        # velocity, zero when the hand was still, and is awake and maybe unsupported: not at rest,
        # whatever it reads
        self.held: np.ndarray = np.zeros(world.num_objects, dtype=bool)
        self.boxes: tuple[np.ndarray, np.ndarray] = local_boxes(world) if boxes is None else boxes
        self._params: np.ndarray | None = None
        self._params_key: bytes = b""
        self._read: tuple[list, list, list] | None = None  # the last read of its dynamic objects
        self._stale: set[int] = set()  # objects whose parameters were left for later (frozen)

    def read(self, skip: set[int] | None = None) -> tuple[list[float], list[float], list[float]]:
        """:meth:`~physics.world.World.read_raw` of its dynamic objects, in order; those in ``skip``
        are taken from the last read instead of asked of pybullet: objects that cannot have moved
        since (frozen, asleep and out of collision detection, and not loaded), whose last read was
        this world's. :meth:`forget` the last read when something else moves them."""
        last = self._read
        fresh = self.dynamic if not skip or last is None else [i for i in self.dynamic if i not in skip]
        if len(fresh) == len(self.dynamic):
            out = self.world.read_raw(self.dynamic)
        else:  # the others asked of pybullet at once, then interleaved with the last read's
            new = self.world.read_raw(fresh) if fresh else ([], [], [])
            flat_p, flat_v, flat_b = [], [], []
            n = 0
            for j, i in enumerate(self.dynamic):
                if i in skip:
                    src, r = last, j
                else:
                    src, r = new, n
                    n += 1
                flat_p += src[0][7 * r:7 * r + 7]
                flat_v += src[1][6 * r:6 * r + 6]
                flat_b += src[2][6 * r:6 * r + 6]
            out = (flat_p, flat_v, flat_b)
        self._read = out
        return out

    def forget(self) -> None:
        """Drop the last read (see :meth:`read`): the world's objects were moved outside an update."""
        self._read = None

    def thaw(self, indices=None) -> None:
        """Put the objects frozen at the last update (those of them in ``indices``; default all) back
        in collision detection (rays then see them); one parked since stays out."""
        if self.frozen:
            back = self.frozen if indices is None else [i for i in self.frozen if i in indices]
            if not back:
                return
            self.world.set_colliding([i for i in back if not self.world.is_parked(i)], True)
            self.frozen = [i for i in self.frozen if i not in back]

    def apply_params(self, params: np.ndarray, skip=()) -> None:
        """Give the objects the parameters ``params (M, 5)`` (:data:`PARAM_NAMES`) where they differ
        from those last applied; not yet to the objects in ``skip`` (frozen for the update: nothing
        can touch them), which get theirs at a later call that does not skip them."""
        key = params.tobytes()
        if key == self._params_key and (not self._stale or self._stale.issubset(skip)):
            return
        w = self.world
        if self._params is None:
            self._params = np.full_like(params, np.nan)
        rows = np.flatnonzero(np.any(params != self._params, axis=1)[w.dynamic_indices])
        self._stale = set()
        for i in w.dynamic_indices[rows].tolist():
            if i in skip:
                self._stale.add(i)
                continue
            row = params[i]
            w.set_dynamics(i, lateral_friction=row[0], rolling_friction=row[1],
                           spinning_friction=row[2], restitution=row[3], mass=row[4])
            self._params[i] = row
        self._params_key = key


def assemble(w0: World, dyn: list[int], read: list[tuple[list, list, list]],
              origins: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre-of-mass poses ``(K, M, 7)``, velocities ``(K, M, 6)`` and AABBs ``(K, M, 2, 3)``, in
    the client frame, from each world's flat read-back of its dynamic objects (static ones from the
    scene, shifted to each world's ``origins (K, 1, 3)``)."""
    K, M, D = len(read), w0.num_objects, len(dyn)
    poses = np.empty((K, M, 7))
    vel = np.zeros((K, M, 6))
    aabbs = np.empty((K, M, 2, 3))
    st = np.ones(M, dtype=bool)
    st[dyn] = False
    if st.any():  # static objects never move: their centre-of-mass poses and boxes from the scene
        sp, sb = w0.static_raw()
        poses[:, st] = sp[st]
        poses[:, st, :3] += origins
        aabbs[:, st] = sb[st] + origins[:, None]
    # the flat lists read into arrays at once (no shape to discover, as np.array of nested lists must)
    for j, (out, shape) in enumerate(((poses, (D, 7)), (vel, (D, 6)), (aabbs, (D, 2, 3)))):
        n = K * int(np.prod(shape))
        out[:, dyn] = np.fromiter(chain.from_iterable(r[j] for r in read), dtype=float, count=n).reshape(K, *shape)
    return poses, vel, aabbs
