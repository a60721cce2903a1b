"""What an update does to objects besides stepping: held objects moved at every step, and objects
pushed out of what they interpenetrate. Hot path: plain lists and direct pybullet calls, every pose
in the world's scene frame and shifted by its ``origin`` only where pybullet is called.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from physics.sleep import near, touching, wake
from physics.transforms import quat_conjugate, quat_from_rotvec, quat_multiply, quat_to_rotvec
from physics.world import World


def hand_offset_walk(error: np.ndarray, dt: float, std: float, time_constant: float,
                     rng: np.random.Generator) -> np.ndarray:
    """One step of the error of a hand-held object's offset to its hand, per particle: ``error (n,
    3)`` m, an Ornstein-Uhlenbeck process that starts at zero when the object is last detected and
    tends to a stationary standard deviation ``std`` (m per axis) with ``time_constant`` (s): the
    grasp slips and the hand turns, which the tracked hand position does not show. Returns the new
    error ``(n, 3)``; ``std = 0`` keeps it at zero."""
    if std <= 0 or len(error) == 0:
        return np.zeros_like(error)
    a = float(np.exp(-dt / time_constant))
    return a * error + np.sqrt(1.0 - a * a) * std * rng.normal(0.0, 1.0, error.shape)


def depenetrate(w: World, indices: list[int], rounds: int = 2) -> None:
    """Push objects ``indices`` out of whatever they interpenetrate, along the deepest contact's
    normal (Bullet would otherwise shoot them out with a spurious velocity). Their velocities are
    kept (pybullet's ``resetBasePositionAndOrientation`` sets them to zero)."""
    c = w.client
    floor = [w.floor_uid] if w.floor_uid >= 0 else []
    for _ in range(rounds):
        moved = False
        for i in indices:
            uid = w.uids[i]
            worst, normal = 0.0, None
            # the floor and the bodies of this world whose boxes overlap its box (the broadphase's answer)
            for o in floor + [w.uids[j] for j in near(w, [i], 0.0)]:
                for pt in pb.getClosestPoints(uid, o, 0.0, physicsClientId=c):
                    if pt[8] < worst:  # contact distance, negative when penetrating
                        worst, normal = pt[8], pt[7]  # normal on B, pointing from B to A
            if normal is not None and worst < -1e-4:
                pos, orn = pb.getBasePositionAndOrientation(uid, physicsClientId=c)
                lin, ang = pb.getBaseVelocity(uid, physicsClientId=c)
                shift = -worst + 1e-4
                pb.resetBasePositionAndOrientation(uid, [pos[k] + normal[k] * shift for k in range(3)], orn,
                                                   physicsClientId=c)
                pb.resetBaseVelocity(uid, lin, ang, physicsClientId=c)  # the reset zeroes it: a rolling can rolls on
                moved = True
        if not moved:
            break


def glide_paths(world: World, start: np.ndarray, end: np.ndarray, indices: np.ndarray,
                n_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paths of held objects gliding from link-frame poses ``start`` to ``end`` ``(H, 7)`` (objects
    ``indices (H,)`` of ``world``'s scene) over ``n_steps`` steps: linearly in position, along the
    shortest arc in orientation. Returns the centre-of-mass frames' positions ``(H, n + 1, 3)`` (m,
    scene frame) and orientations ``(H, n + 1, 4)`` (what pybullet sets: turned from the link
    frame's where an object's inertial frame is) before each step (the last entry: after the last
    step), and the constant linear ``(H, 3)`` (m/s, of the centre of mass: what pybullet sets) and
    angular ``(H, 3)`` (rad/s) velocities. The linear one takes the centre of mass from its start to
    its end: the link origin's velocity, plus, for an object that turns with its centre of mass off
    its link origin, the chord of the arc that centre makes about it."""
    n = max(1, int(n_steps))
    frac = (np.arange(n + 1) / n)[None, :, None]  # pose before step s is at frac[s - 1]; after the last, at 1
    rv = quat_to_rotvec(quat_multiply(end[:, 3:], quat_conjugate(start[:, 3:])))  # (H, 3) shortest rotation
    pos = start[:, None, :3] + frac * (end[:, None, :3] - start[:, None, :3])
    orn = quat_multiply(quat_from_rotvec(frac * rv[:, None, :]), np.broadcast_to(start[:, None, 3:], pos.shape[:2] + (4,)))
    off = world.com_frame(np.concatenate([pos, orn], axis=-1).swapaxes(0, 1), None, indices)[0]
    dt = n * world.settings.time_step
    off = off.swapaxes(0, 1)
    # the centre of mass about the link origin (R c) at the end less at the start: exactly zero
    # unless the object turns with its centre off its link origin
    ends = np.zeros((2, len(start), 7))
    ends[..., 3:] = orn[:, [0, -1]].swapaxes(0, 1)
    about = world.com_frame(ends, None, indices)[0][..., :3]
    lever = about[1] - about[0]
    return off[..., :3], off[..., 3:], (end[:, :3] - start[:, :3]) / dt + lever / dt, rv / dt


def held_glides(worlds: list[World], poses: np.ndarray, targets: np.ndarray, held: np.ndarray,
                alone: np.ndarray, n_steps: int) -> dict[int, list[tuple]]:
    """The glide paths (:func:`glide_paths`) of all objects ``held (K, M)`` of the K ``worlds`` (copies
    of one scene) from link-frame ``poses (K, M, 7)`` to ``targets (K, M, 7)`` over ``n_steps``,
    computed in one pass: ``{k: [(body id, com, orn, lin, ang, index or None), ...]}`` as lists in
    the client frame, with the object's index where it is ``alone (K, M)``
    (:func:`~estimator.worlds.frozen.alone`: placed at its glide's end only, its path is that end
    alone). For :func:`~estimator.worlds.propagate.propagate_batch`, whose worlds hold ``poses``."""
    kk, ii = np.nonzero(held)
    if len(kk) == 0:
        return {}
    com, orn, lin, ang = glide_paths(worlds[0], poses[kk, ii], targets[kk, ii], ii, n_steps)
    com = com + np.array([worlds[k].origin for k in kk.tolist()])[:, None, :]
    lone = alone[kk, ii]
    # one conversion per array for all the paths, one for the ends of those alone (a call per path
    # and array cost more than the paths), put back in order
    paths = iter(zip(com[~lone].tolist(), orn[~lone].tolist()))
    ends = iter(zip(com[lone, -1:].tolist(), orn[lone, -1:].tolist()))
    out: dict[int, list[tuple]] = {}
    for k, i, v, a, end_only in zip(kk.tolist(), ii.tolist(), lin.tolist(), ang.tolist(), lone.tolist()):
        c, o = next(ends) if end_only else next(paths)
        out.setdefault(k, []).append((worlds[k].uids[i], c, o, v, a, i if end_only else None))
    return out


class HeldObjects:
    """Moves held objects at every step (hot path: plain lists, direct pybullet calls).

    Objects held since the start of the update glide from where they were to their target, linearly
    in position and along the shortest arc in orientation, with the matching velocity, so that the
    contact solver moves what they carry or push (a tilted box pours its contents out). Objects that
    become held during the update (a divergence) jump to their target at once and take their contents
    with them rigidly, rotation included, as Algorithm 1 does.

    ``com_start`` (M lists of 3, client frame) and ``com_orn (M, 4)``: the centre-of-mass frames of
    the targets (what pybullet sets), computed for all the worlds at once by the caller: positions
    at the update's start (with ``moving``, the target moves at its velocity and reaches its pose at
    the update's end: moved back by ``n_steps`` steps) and orientations. ``target_vel (M, 6)``:
    the targets' velocities (linear of the link origin, angular); ``contents (M, M)`` bool:
    ``[j, i]``, object ``j`` is in ``i``.
    """

    def __init__(self, w: World, com_start: list, com_orn: np.ndarray, target_vel: np.ndarray,
                 contents: np.ndarray, n_steps: int, moving: bool = False):
        self.w = w
        self.com_start = com_start
        self.com_orn = com_orn
        self.tvel = target_vel
        self.contents = contents
        self.n = max(1, int(n_steps))
        self.moving = bool(moving)
        self.items: list[tuple] = []  # (body id, per-step com positions, per-step orientations, lin, ang)
        self.ends: list[tuple] = []  # (index, body id, com position, orientation, lin, ang): placed at the end

    def glide(self, uid: int, com: list, orn: list, lin: list, ang: list, alone: int | None = None) -> None:
        """Add an object held from the start of the update, along the path of :func:`glide_paths`:
        centre-of-mass positions ``com`` and orientations ``orn`` before each step (``n + 1``
        entries, client frame) and the matching velocity ``lin``, ``ang``. ``alone``: its index,
        when nothing can touch it nor it anything during the update
        (:func:`~estimator.worlds.frozen.alone`): it is then out of collision detection until its
        glide's end, where it is placed, and costs no call at the steps."""
        if alone is None:
            self.items.append((uid, com, orn, lin, ang))
        else:
            self.w.set_colliding([alone], False)
            self.ends.append((alone, uid, com[-1], orn[-1], lin, ang))

    def jump(self, indices: list[int], step: int | None = None) -> None:
        """Add objects that became held after step ``step`` (default: the last): move them (and their
        contents) to the target at once, waking them and what they touched (see
        :attr:`PhysicsSettings.sleeping`), out of their parking if they were parked. With ``moving``,
        a target moves at its velocity and reaches its pose at the update's end: the objects follow
        it from where it is now. Plain floats: no array work (many worlds may see an object let go
        at the same step)."""
        w = self.w
        if w.settings.sleeping:
            wake(w, sorted(set(indices) | set(touching(w, indices)) | set(
                int(j) for i in indices for j in np.flatnonzero(self.contents[:, i]))))
        s = self.n if step is None else min(int(step), self.n)
        dt = w.settings.time_step
        for i in indices:
            self._jump_one(i, s, dt, self._carried(i, indices))

    def _carried(self, i: int, indices: list[int]) -> list[tuple]:
        """What object ``i`` carries when it jumps: ``(index, centre-of-mass position, orientation,
        angular velocity)`` of its contents (the held ones excepted: they are set on their own paths
        before the next step, and those jumping with it)."""
        w, c = self.w, self.w.client
        held = {item[0] for item in self.items}
        out = []
        for j in np.flatnonzero(self.contents[:, i]).tolist():
            uid = w.uids[j]
            if uid not in held and j not in indices:
                pos, orn = pb.getBasePositionAndOrientation(uid, physicsClientId=c)
                out.append((j, pos, orn, pb.getBaseVelocity(uid, physicsClientId=c)[1]))
        return out

    def _jump_one(self, i: int, s: int, dt: float, carried: list[tuple]) -> None:
        """:meth:`jump` of object ``i`` (woken already) to where its target is before step ``s + 1``,
        with what it carries (:meth:`_carried`) moved rigidly with it."""
        w = self.w
        start = self.com_start[i]
        if self.moving:
            tv = self.tvel[i, :3].tolist()
            path = [[start[0] + tv[0] * (t * dt), start[1] + tv[1] * (t * dt), start[2] + tv[2] * (t * dt)]
                    for t in range(self.n + 1)]
        else:
            path = [start] * (self.n + 1)
        orn = self.com_orn[i].tolist()
        v = self.tvel[i].tolist()
        lin = _com_velocity(v[:3], v[3:], orn, w.link_origins[i].tolist())
        if carried:  # a rigid motion of the centres of mass is that of the link frames
            p0, q0 = pb.getBasePositionAndOrientation(w.uids[i], physicsClientId=w.client)
            turn = _qmul(orn, (-q0[0], -q0[1], -q0[2], q0[3]))  # before -> after
            for j, pos, q, ang in carried:
                off = _qrot(turn, [pos[0] - p0[0], pos[1] - p0[1], pos[2] - p0[2]])
                q = _qmul(turn, q)
                # its link origin takes the target's velocity, and it keeps its spin
                w.load_com_state([j], [[path[s][a] + off[a] for a in range(3)] + q],
                                 [_com_velocity(v[:3], ang, q, w.link_origins[j].tolist()) + list(ang)])
        w.load_com_state([i], [path[s] + orn], [lin + v[3:]])
        self.items.append((w.uids[i], path, [orn] * (self.n + 1), lin, v[3:]))

    def apply(self, s: int) -> None:
        """Place the held objects where they are before step ``s`` (1-based; ``n + 1``: the end)."""
        c = self.w.client
        reset, reset_vel = pb.resetBasePositionAndOrientation, pb.resetBaseVelocity
        k = min(s - 1, self.n)
        for uid, pos, orn, lin, ang in self.items:
            reset(uid, pos[k], orn[k], physicsClientId=c)
            reset_vel(uid, lin, ang, physicsClientId=c)
        if s > self.n and self.ends:
            for i, uid, pos, orn, lin, ang in self.ends:
                reset(uid, pos, orn, physicsClientId=c)
                reset_vel(uid, lin, ang, physicsClientId=c)
            self.w.set_colliding([e[0] for e in self.ends if not self.w.is_parked(e[0])], True)
            self.ends = []


def _com_velocity(lin: list, ang: list, orn: list, origin: list) -> list[float]:
    """The velocity of a body's centre of mass (3 floats) when its link origin moves at ``lin`` and
    it turns at ``ang`` (world frame), its centre-of-mass frame turned by ``orn`` (x, y, z, w) and
    its link origin at ``origin`` in that frame (:attr:`~physics.world.World.link_origins`): the
    centre is at ``-R o`` from the origin."""
    d = _qrot(orn, origin)
    return [lin[0] - (ang[1] * d[2] - ang[2] * d[1]), lin[1] - (ang[2] * d[0] - ang[0] * d[2]),
            lin[2] - (ang[0] * d[1] - ang[1] * d[0])]


def _qmul(a, b) -> list[float]:
    """Hamilton product ``a * b`` of two quaternions (x, y, z, w) given as sequences of floats."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def _qrot(q, v) -> list[float]:
    """Vector ``v`` (3 floats) rotated by the unit quaternion ``q`` (x, y, z, w)."""
    x, y, z, w = q
    # v + 2 w (u x v) + 2 u x (u x v), u the vector part
    tx, ty, tz = 2.0 * (y * v[2] - z * v[1]), 2.0 * (z * v[0] - x * v[2]), 2.0 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)]
