"""A pybullet world built from a :class:`~physics.scene.Scene`, with named, array-based access.

One :class:`World` owns one DIRECT pybullet client; every pybullet call names that client, and the
client is closed by :meth:`World.close` (or by leaving a ``with`` block), never by a finaliser.

Arrays (float64):

* poses ``(M, 7)``: position (m) and orientation quaternion (x, y, z, w) of each object's base
  *link frame* (the URDF frame, not pybullet's centre-of-mass frame);
* velocities ``(M, 6)``: linear (m/s, of the link-frame origin) and angular (rad/s), world frame;
* AABBs ``(M, 2, 3)``: world-frame ``[min, max]`` corners.

``M`` is the number of objects of the scene, in scene order; :attr:`World.object_ids` names them.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from .bodies import apply_dynamics, create_body
from .rays import ray_cast
from .scene import ObjectSpec, Scene
from .settings import PhysicsSettings, connect
from .transforms import com_from_link, link_from_com, pose_inverse

FLOOR = -2
"""Body index returned by ray queries for the floor plane (``-1`` means nothing was hit)."""

PARK_DISTANCE = 50.0
PARK_DEPTH = 25.0
"""An object set more than this (m) below the floor is parked: it collides with nothing and sleeps."""
class World:
    """A physics world holding the objects of ``scene`` (plus an optional floor plane at z = 0).

    A world owns its pybullet client, or is one of several copies of a scene side by side in a
    shared client (:class:`~physics.group.WorldGroup`): then ``origin`` (m) is where this copy's
    scene frame sits in the client, every method takes and returns poses in the scene frame (except
    the raw hot-path methods, which say so), and stepping or saving the state concerns the whole
    client.

    Objects whose scene pose is ``None`` are *parked* until the caller sets a pose: far below the
    floor, colliding with nothing and asleep, so that they stay where they are;
    :attr:`parked_pose` gives the pose used. Setting any pose more than :data:`PARK_DEPTH` below
    the floor parks an object, any other pose un-parks it.
    """

    def __init__(self, scene: Scene, settings: PhysicsSettings | None = None, *,
                 client: int | None = None, origin=(0.0, 0.0, 0.0), floor_uid: int = -1,
                 shapes: dict[int, int] | None = None):
        self.scene = scene
        self.settings = settings or PhysicsSettings()
        self.object_ids: tuple[str, ...] = scene.object_ids
        self._index = {oid: i for i, oid in enumerate(self.object_ids)}
        self.origin = np.asarray(origin, dtype=float).reshape(3)
        self._owns_client = client is None
        self._shapes = {} if shapes is None else shapes  # collision shape per object, shared by copies
        if client is None:
            client, floor_uid = connect(self.settings, scene.floor)
        self.client, self.floor_uid = client, floor_uid
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    # -- life cycle ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Disconnect the pybullet client (a copy in a shared client leaves it to its group). Safe to call twice."""
        if getattr(self, "client", -1) >= 0:
            if self._owns_client:
                try:
                    pb.disconnect(physicsClientId=self.client)
                except pb.error:
                    pass
            self.client = -1

    @property
    def closed(self) -> bool:
        return self.client < 0

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- building -----------------------------------------------------------------------------------
    def _build(self) -> None:
        c = self.client
        uids, offsets, static = [], [], []
        for i, spec in enumerate(self.scene.objects):
            uid = self._create(i, spec)
            uids.append(uid)
            info = pb.getDynamicsInfo(uid, -1, physicsClientId=c)
            offsets.append(list(info[3]) + list(info[4]))
            static.append(spec.static)
            # sleeping only where the settings allow it (a reset does not wake a body), and no air
            # drag (Bullet's default linear damping of 0.04 would slow free falls by about 1 % per
            # second). Bullet's default angular damping brakes a rolling ball like a drag in
            # proportion to its speed (0.35 m/s^2 at 1 m/s for a 3 cm ball): where the scene states
            # a rolling friction that is what resists rolling, and the damping is taken off so that
            # it is not counted twice (and the friction can be learnt from a seen roll,
            # :class:`~estimator.model.terms.VelocityTerm`); elsewhere it stays, the only rolling
            # resistance of an object whose scene is silent about it
            pb.changeDynamics(uid, -1, activationState=self._activation, linearDamping=0.0, physicsClientId=c)
            if spec.rolling_friction is not None:
                pb.changeDynamics(uid, -1, angularDamping=0.0, physicsClientId=c)
        self.uids: tuple[int, ...] = tuple(uids)
        self._uid_to_index = {u: i for i, u in enumerate(uids)}
        self.static = np.array(static, dtype=bool)
        self.dynamic_indices = np.flatnonzero(~self.static)
        off = np.array(offsets, dtype=float).reshape(len(uids), 7)
        self._inertial = off  # centre-of-mass frame expressed in the link frame
        self._has_offset = bool(np.any(np.abs(off[:, :3]) > 1e-12)
                                or np.any(np.abs(off[:, 3:6]) > 1e-12))
        self._inertial_inv = pose_inverse(off)
        self.link_origins = self._inertial_inv[:, :3]  # (M, 3) m: link origin o in the com frame (at c + R o)
        self._num_links = [pb.getNumJoints(u, physicsClientId=c) for u in uids]
        self._static_raw: tuple[np.ndarray, np.ndarray] | None = None
        self._parked: set[int] = set()
        self.parked_pose = np.zeros((len(uids), 7))
        self.parked_pose[:, 0] = PARK_DISTANCE + 3.0 * np.arange(len(uids))
        self.parked_pose[:, 1] = PARK_DISTANCE
        self.parked_pose[:, 2] = -PARK_DISTANCE
        self.parked_pose[:, 6] = 1.0
        initial = self.parked_pose.copy()
        for i, spec in enumerate(self.scene.objects):
            if spec.position is not None:
                initial[i, :3] = spec.position
                initial[i, 3:] = spec.orientation
        self.set_poses(initial)
        self.set_velocities(np.zeros((len(uids), 6)))

    @property
    def _activation(self) -> int:
        return (pb.ACTIVATION_STATE_ENABLE_SLEEPING if self.settings.sleeping
                else pb.ACTIVATION_STATE_DISABLE_SLEEPING)

    def _create(self, i: int, spec: ObjectSpec) -> int:
        pos = list(spec.position) if spec.position is not None else [0.0, 0.0, -PARK_DISTANCE]
        return create_body(self.client, spec, (np.asarray(pos) + self.origin).tolist(), self._shapes, i,
                           collision_only=self.settings.collision_only, source=self.scene.source)

    # -- named access -------------------------------------------------------------------------------
    @property
    def num_objects(self) -> int:
        return len(self.uids)

    def index(self, object_id: str) -> int:
        """Index of ``object_id`` in the arrays of this world. ``KeyError`` if unknown."""
        return self._index[object_id]

    def index_of_uid(self, uid: int) -> int:
        """Object index of a pybullet body id; :data:`FLOOR` for the floor, -1 for anything else."""
        if uid == self.floor_uid and uid >= 0:
            return FLOOR
        return self._uid_to_index.get(uid, -1)

    # -- poses and velocities -----------------------------------------------------------------------
    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(len(self.uids)))
        return [int(i) for i in np.atleast_1d(indices)]

    def get_poses(self, indices=None) -> np.ndarray:
        """Link-frame poses ``(n, 7)`` of the objects ``indices`` (default: all, in scene order)."""
        idx = self._indices(indices)
        c = self.client
        flat: list[float] = []
        get = pb.getBasePositionAndOrientation
        for i in idx:
            p, q = get(self.uids[i], physicsClientId=c)
            flat.extend(p + q)
        raw = np.array(flat, dtype=float).reshape(len(idx), 7)
        raw[:, :3] -= self.origin
        return self.link_frame(raw, None, idx)[0]

    def set_poses(self, poses: np.ndarray, indices=None) -> None:
        """Teleport objects ``indices`` to link-frame ``poses`` ``(n, 7)``. Velocities are kept.
        Sleeping bodies are not woken (see :func:`physics.sleep.wake`)."""
        idx = self._indices(indices)
        poses = self.com_frame(np.asarray(poses, dtype=float).reshape(len(idx), 7), None, idx)[0].copy()
        self._park(idx, poses[:, 2])
        poses[:, :3] += self.origin
        c = self.client
        reset, get_vel, set_vel = pb.resetBasePositionAndOrientation, pb.getBaseVelocity, pb.resetBaseVelocity
        for i, row in zip(idx, poses.tolist()):
            uid = self.uids[i]
            lin, ang = get_vel(uid, physicsClientId=c)
            reset(uid, row[:3], row[3:], physicsClientId=c)  # (which zeroes the velocity)
            set_vel(uid, lin, ang, physicsClientId=c)

    def get_velocities(self, indices=None) -> np.ndarray:
        """Velocities ``(n, 6)``: linear velocity of the link-frame origin and angular velocity."""
        idx = self._indices(indices)
        p, v, _ = self.read_raw(idx)
        n = len(idx)
        return self.link_frame(np.array(p).reshape(n, 7), np.array(v).reshape(n, 6), idx)[1]

    def set_velocities(self, velocities: np.ndarray, indices=None) -> None:
        """Set velocities ``(n, 6)`` (linear of the link-frame origin, angular), world frame."""
        idx = self._indices(indices)
        vel = np.array(velocities, dtype=float).reshape(len(idx), 6)
        if self._has_offset and np.any(vel[:, 3:] != 0.0):  # not turning: the origin's velocity is the centre's
            vel = self.com_frame(self.get_poses(idx), vel, idx)[1]
        c = self.client
        for i, row in zip(idx, vel.tolist()):
            pb.resetBaseVelocity(self.uids[i], row[:3], row[3:], physicsClientId=c)

    def read_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Poses ``(M, 7)``, velocities ``(M, 6)`` and AABBs ``(M, 2, 3)`` of all objects, read in one pass."""
        m = len(self.uids)
        flat_p, flat_v, flat_b = self.read_raw(range(m))
        raw = np.array(flat_p).reshape(m, 7)
        raw[:, :3] -= self.origin
        poses, vel = self.link_frame(raw, np.array(flat_v).reshape(m, 6))
        return poses, vel, np.array(flat_b).reshape(m, 2, 3) - self.origin

    def load_com_state(self, indices: list[int], com_poses: list, com_vel: list) -> None:
        """Set objects ``indices`` to centre-of-mass poses and velocities given as nested lists
        ``[[x, y, z, qx, qy, qz, qw], ...]`` (in the client's frame: scene frame plus
        :attr:`origin`) and ``[[vx, vy, vz, wx, wy, wz], ...]`` (the hot load path; :meth:`com_frame`
        converts link-frame arrays). Sleeping bodies are not woken (see :func:`physics.sleep.wake`)."""
        c = self.client
        reset, reset_vel = pb.resetBasePositionAndOrientation, pb.resetBaseVelocity
        floor = self.origin[2] - PARK_DEPTH
        if self._parked or any(p[2] < floor for p in com_poses):
            self._park(indices, [p[2] - self.origin[2] for p in com_poses])
        for i, p, v in zip(indices, com_poses, com_vel):
            uid = self.uids[i]
            reset(uid, p[:3], p[3:], physicsClientId=c)
            reset_vel(uid, v[:3], v[3:], physicsClientId=c)

    def is_parked(self, index: int) -> bool:
        """Whether object ``index`` is parked (see the class docstring)."""
        return index in self._parked

    def set_colliding(self, indices, on: bool) -> None:
        """Put objects ``indices`` (all links) in collision detection (``on``: group 1, mask all, pybullet's for a
        dynamic body) or out of it (group and mask 0: no contact, no pair, rays miss it; Bullet drops its contacts)."""
        group, mask = (1, -1) if on else (0, 0)
        for i in indices:
            for link in range(-1, self._num_links[i]):
                pb.setCollisionFilterGroupMask(self.uids[i], link, group, mask, physicsClientId=self.client)

    def _park(self, indices, heights) -> None:
        """Park dynamic objects ``indices`` set at ``heights`` (m, scene frame) below
        :data:`PARK_DEPTH` (no collisions, asleep, at rest) and un-park the others."""
        c = self.client
        for i, z in zip(indices, heights):
            if self.static[i]:
                continue
            parked = z < -PARK_DEPTH
            if parked == (i in self._parked):
                continue
            uid = self.uids[i]
            self.set_colliding([i], not parked)
            if parked:
                self._parked.add(i)
                pb.resetBaseVelocity(uid, [0, 0, 0], [0, 0, 0], physicsClientId=c)
                pb.changeDynamics(uid, -1, activationState=pb.ACTIVATION_STATE_ENABLE_SLEEPING, physicsClientId=c)
                pb.changeDynamics(uid, -1, activationState=pb.ACTIVATION_STATE_SLEEP, physicsClientId=c)
            else:
                self._parked.discard(i)
                pb.changeDynamics(uid, -1, activationState=self._activation, physicsClientId=c)
                pb.changeDynamics(uid, -1, activationState=pb.ACTIVATION_STATE_WAKE_UP, physicsClientId=c)

    def static_raw(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre-of-mass poses ``(M, 7)`` and AABBs ``(M, 2, 3)`` of all objects in the scene frame,
        as read when first asked (valid for the static objects, which never move; the other rows are NaN)."""
        if self._static_raw is None:
            m = len(self.uids)
            st = [int(i) for i in np.flatnonzero(self.static)]
            p, _, b = self.read_raw(st)
            poses = np.full((m, 7), np.nan)
            boxes = np.full((m, 2, 3), np.nan)
            poses[st] = np.array(p).reshape(len(st), 7)
            poses[st, :3] -= self.origin
            boxes[st] = np.array(b).reshape(len(st), 2, 3) - self.origin
            self._static_raw = (poses, boxes)
        return self._static_raw

    def read_raw(self, indices, flat_p: list | None = None, flat_v: list | None = None,
                 flat_b: list | None = None) -> tuple[list[float], list[float], list[float]]:
        """Pybullet's own state of objects ``indices``, as flat lists (the hot read-back path: no
        numpy): centre-of-mass poses (7 floats per object), centre-of-mass velocities (6) and AABBs
        (6: ``lo, hi``, the union over all links), positions in the client's frame (scene frame
        plus :attr:`origin`). :meth:`link_frame` converts the first two.
        Given lists are extended in place (and returned)."""
        c = self.client
        get, get_vel, get_box = pb.getBasePositionAndOrientation, pb.getBaseVelocity, pb.getAABB
        flat_p = [] if flat_p is None else flat_p
        flat_v = [] if flat_v is None else flat_v
        flat_b = [] if flat_b is None else flat_b
        links = self._num_links
        for i in indices:
            uid = self.uids[i]
            p, q = get(uid, physicsClientId=c)
            v, a = get_vel(uid, physicsClientId=c)
            lo, hi = get_box(uid, -1, physicsClientId=c)
            flat_p += p
            flat_p += q
            flat_v += v
            flat_v += a
            if links[i]:
                lo, hi = list(lo), list(hi)
                for link in range(links[i]):
                    a_lo, a_hi = get_box(uid, link, physicsClientId=c)
                    lo = [min(x, y) for x, y in zip(lo, a_lo)]
                    hi = [max(x, y) for x, y in zip(hi, a_hi)]
            flat_b += lo
            flat_b += hi
        return flat_p, flat_v, flat_b

    def link_frame(self, com_poses: np.ndarray, com_vel: np.ndarray | None = None,
                   indices=None) -> tuple[np.ndarray, np.ndarray | None]:
        """Pybullet's centre-of-mass poses ``(..., n, 7)`` and velocities ``(..., n, 6)`` (or None)
        of objects ``indices`` (default: all M; any leading axes, e.g. particles) to link-frame
        poses and link-origin velocities."""
        if not self._has_offset:
            return com_poses, com_vel
        idx = slice(None) if indices is None else self._indices(indices)
        return link_from_com(com_poses, com_vel, self._inertial[idx], self._inertial_inv[idx])

    def com_frame(self, poses: np.ndarray, vel: np.ndarray | None = None,
                  indices=None) -> tuple[np.ndarray, np.ndarray | None]:
        """The inverse of :meth:`link_frame`: link-frame poses ``(..., n, 7)`` and link-origin
        velocities ``(..., n, 6)`` (or None) of objects ``indices`` (default: all M) to pybullet's
        centre-of-mass ones."""
        if not self._has_offset:
            return poses, vel
        return com_from_link(poses, vel, self._inertial[slice(None) if indices is None else self._indices(indices)])

    def step(self, n: int = 1) -> None:
        """Advance the simulation by ``n`` fixed steps of :attr:`PhysicsSettings.time_step` seconds
        (every copy of a shared client)."""
        c = self.client
        for _ in range(int(n)):
            pb.stepSimulation(physicsClientId=c)

    # -- physical parameters ------------------------------------------------------------------------
    def set_dynamics(self, index: int, *, lateral_friction: float | None = None,
                     rolling_friction: float | None = None, spinning_friction: float | None = None,
                     restitution: float | None = None, mass: float | None = None) -> None:
        """Change physical parameters of object ``index``; ``None`` leaves a parameter unchanged."""
        # one call (the hot path of a particle's parameters); a static object keeps its zero mass
        apply_dynamics(self.client, self.uids[index], lateral_friction, rolling_friction, spinning_friction,
                       restitution, mass=None if self.static[index] else mass)

    def get_dynamics(self, index: int) -> dict[str, float]:
        """Mass (kg), lateral / rolling / spinning friction and restitution of object ``index``."""
        info = pb.getDynamicsInfo(self.uids[index], -1, physicsClientId=self.client)
        return {"mass": info[0], "lateral_friction": info[1], "restitution": info[5],
                "rolling_friction": info[6], "spinning_friction": info[7]}

    # -- queries ------------------------------------------------------------------------------------
    def aabbs(self, indices=None) -> np.ndarray:
        """World-frame axis-aligned bounding boxes ``(n, 2, 3)`` (all links of each body)."""
        idx = self._indices(indices)
        c = self.client
        flat: list[float] = []
        get = pb.getAABB
        multi = []
        for k, i in enumerate(idx):
            lo, hi = get(self.uids[i], -1, physicsClientId=c)
            flat.extend(lo + hi)
            if self._num_links[i]:
                multi.append((k, i))
        out = np.array(flat, dtype=float).reshape(len(idx), 2, 3)
        for k, i in multi:  # articulated bodies: the union over their links
            for link in range(self._num_links[i]):
                a, b = get(self.uids[i], link, physicsClientId=c)
                out[k, 0] = np.minimum(out[k, 0], a)
                out[k, 1] = np.maximum(out[k, 1], b)
        return out - self.origin

    def in_contact(self, a: int, b: int | None = None) -> bool:
        """True when object ``a`` touches object ``b`` (or anything, if ``b`` is None; the floor is
        :data:`FLOOR`). Uses the contacts of the last step."""
        kw = {"bodyA": self.uids[a], "physicsClientId": self.client}
        if b is not None:
            kw["bodyB"] = self.floor_uid if b == FLOOR else self.uids[b]
        return len(pb.getContactPoints(**kw)) > 0

    def ray_test(self, origins: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cast rays ``origins`` -> ``ends`` ``(N, 3)`` (scene frame).

        Returns ``(hit_index (N,) int, hit_fraction (N,) float)``: the object index of the first hit
        (:data:`FLOOR` for the floor, -1 for none) and the fraction of the ray's length where it hit
        (1.0 for none).
        """
        uids, frac = ray_cast(self.client, np.asarray(origins, dtype=float).reshape(-1, 3) + self.origin,
                              np.asarray(ends, dtype=float).reshape(-1, 3) + self.origin)
        hit = np.array([self.index_of_uid(u) if u >= 0 else -1 for u in uids.tolist()], dtype=int)
        return hit, frac

    def save_state(self) -> int:
        """Save the full simulation state in memory; returns an id for :meth:`restore_state`."""
        return pb.saveState(physicsClientId=self.client)

    def restore_state(self, state_id: int) -> None:
        """Restore a state saved by :meth:`save_state`."""
        pb.restoreState(stateId=state_id, physicsClientId=self.client)

    def remove_state(self, state_id: int) -> None:
        """Free a state saved by :meth:`save_state`."""
        pb.removeState(state_id, physicsClientId=self.client)
