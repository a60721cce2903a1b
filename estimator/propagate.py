"""Advance one particle's world through one update: Algorithm 1 of the physics reasoner.

This is the hot path, run in the worker that owns the world. It takes and returns plain arrays so that
worker processes exchange only numpy data. One call simulates ``n_steps`` fixed steps and, at every
step:

* HELD objects move to their target pose (the perception, a tracked hand, or where they were last
  seen): smoothly over the update for objects held from its start (physics moves what they carry),
  at once, with their contents carried rigidly, for objects that become held during it;
* FREE objects that are checked (perceived, dynamic) and whose simulated position diverges from the
  perceived one by more than ``d_sim_perc`` switch to HELD (they are not physically plausible: an agent
  must be moving them) and are overridden from that step on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from actions.modes import FREE, HELD
from physics.transforms import (carry_pose, quat_conjugate, quat_from_rotvec, quat_multiply,
                                quat_to_rotvec)
from physics.world import World

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
                "depenetrate", "reset")
"""The fields of :class:`BatchInput` with a leading particle axis."""


@dataclass
class BatchOutput(StepOutput):
    """Outputs for K particles: the fields of :class:`StepOutput` with a leading K axis (``finite
    (K,)``), plus ``visible (K, M)``: fraction of each object's sample points seen by the camera (0
    where not queried)."""

    visible: np.ndarray | None = None


class ParticleWorld:
    """A persistent world for one particle slot, remembering the parameters last applied."""

    def __init__(self, world: World):
        self.world = world
        self.dynamic = [int(i) for i in world.dynamic_indices]
        self._params: np.ndarray | None = None
        self._params_key: bytes = b""

    def apply_params(self, params: np.ndarray) -> None:
        key = params.tobytes()
        if key == self._params_key:
            return
        w = self.world
        for i in w.dynamic_indices:
            row = params[i]
            if self._params is not None and np.array_equal(row, self._params[i]):
                continue
            w.set_dynamics(int(i), lateral_friction=row[0], rolling_friction=row[1],
                           spinning_friction=row[2], restitution=row[3], mass=row[4])
        self._params = params.copy()
        self._params_key = key


MAX_SPEED = 50.0  # m/s: anything faster is a simulation that exploded


A_MAX = 9.81
"""Bound on an object's acceleration (m/s^2) between two divergence tests when checks are lazy:
gravity's, the only force that acts without a contact (an object in flight, sliding or rolling
down a slope accelerates at most this much; one pushed or hit may exceed it and is then tested a
few steps late, at the latest after the last step)."""


def propagate(pw: ParticleWorld, inp: StepInput, n_steps: int, d_sim_perc: float,
              lazy: bool = False) -> StepOutput:
    """Run Algorithm 1 for ``n_steps`` steps in one particle's world (see :func:`propagate_batch`)."""
    batch = BatchInput(*(None if getattr(inp, f) is None else np.asarray(getattr(inp, f))[None]
                         for f in PER_PARTICLE))
    out = propagate_batch([pw], batch, n_steps, d_sim_perc, lazy)
    return StepOutput(out.poses[0], out.velocities[0], out.modes[0], out.max_divergence[0], out.aabbs[0],
                      bool(out.finite[0]))


LAST_STEPS = 2
"""With lazy tests, a test that falls due in the last this many steps of an update is left to the
test after the last step (at most this many steps late)."""


def _due_steps(d: np.ndarray, v: np.ndarray, d_sim_perc: float, dt: float) -> np.ndarray:
    """First step (>= 1) at which an object at divergence ``d`` (m) moving at ``v`` (m/s) and
    accelerating at most at :data:`A_MAX` could have crossed ``d_sim_perc``."""
    room = np.maximum(d_sim_perc - d, 0.0)
    tau = (-v + np.sqrt(v * v + 2.0 * A_MAX * room)) / A_MAX
    return np.maximum(1, (tau / dt).astype(np.int64))


def propagate_batch(pws: list[ParticleWorld], batch: BatchInput, n_steps: int, d_sim_perc: float,
                    lazy: bool = False) -> BatchOutput:
    """Run Algorithm 1 for ``n_steps`` steps in each of the K worlds ``pws`` (all built from the same
    scene), particle ``k`` from the state in row ``k`` of ``batch``.

    With ``lazy=False`` the divergence of every free perceived object is tested after every step, as
    the paper does. With ``lazy=True`` an object is tested again only at the first step at which,
    starting from its present divergence ``d`` and speed ``v`` and accelerating at most at
    :data:`A_MAX`, it could have crossed ``d_sim_perc``, and after the last step: exact for objects
    moving freely or resting, late by a few steps only when something hits an object hard.

    Array work is done once for the K worlds (frame conversions, first test steps, the finiteness
    test); each world's loop is plain Python around direct pybullet calls. A world's result depends
    only on its own row of ``batch``, so that sharding the particles does not change any output.
    Returns a :class:`BatchOutput` whose ``visible`` is all zeros.
    """
    K = len(pws)
    if K == 0:
        raise ValueError("propagate_batch needs at least one world")
    w0 = pws[0].world
    M = w0.num_objects
    if batch.poses.shape != (K, M, 7):
        raise ValueError(f"batch.poses must have shape ({K}, {M}, 7), got {batch.poses.shape}")
    dyn = pws[0].dynamic
    dt = w0.settings.time_step
    n_steps = int(n_steps)
    dyn_mask = np.zeros(M, dtype=bool)
    dyn_mask[dyn] = True
    modes_out = batch.modes.copy()
    # loads: centre-of-mass poses and velocities of the entries to reset, as nested lists
    reset = np.broadcast_to(dyn_mask, (K, M)) if batch.reset is None else batch.reset & dyn_mask
    any_reset = reset.any(axis=1).tolist()
    com_p, com_v = w0.com_frame(batch.poses, batch.velocities)
    reset_l, depen_l = reset.tolist(), (batch.depenetrate & dyn_mask).tolist()
    held_l = ((batch.modes == HELD) & dyn_mask).tolist()
    # watched objects and the first step at which each one needs testing
    checked = batch.check & (batch.modes == FREE) & dyn_mask
    target_com = w0.com_frame(batch.target)[0][..., :3]
    due = np.ones((K, M), dtype=np.int64)
    if lazy:
        d0 = np.linalg.norm(com_p[..., :3] - target_com, axis=-1)
        due = _due_steps(d0, np.linalg.norm(com_v[..., :3], axis=-1), d_sim_perc, dt)
    checked_l, target_l, due_l = checked.tolist(), target_com.tolist(), due.tolist()
    # the read-back, for all K worlds: dynamic objects from the worlds, static ones fixed
    D = len(dyn)
    raw_p: list[float] = []
    raw_v: list[float] = []
    raw_b: list[float] = []
    tested: list[tuple[int, int, float]] = []  # (particle, object, largest divergence) of in-loop tests
    switched_at: list[tuple[int, int, float]] = []
    for k, pw in enumerate(pws):
        w = pw.world
        pw.apply_params(batch.params[k])
        if any_reset[k]:
            rows = [i for i in dyn if reset_l[k][i]]
            w.load_com_state(rows, com_p[k, rows].tolist(), com_v[k, rows].tolist())
        if True in depen_l[k]:
            depenetrate(w, [i for i in dyn if depen_l[k][i]])
        held = _Overrider(w, batch.target[k], batch.target_vel[k], batch.contents[k], n_steps)
        if True in held_l[k]:
            held.glide([i for i in dyn if held_l[k][i]])
        # [index, body id, x, y, z of the perceived centre of mass, next step to test, largest divergence]
        watch = [[i, w.uids[i], *target_l[k][i], due_l[k][i], 0.0] for i in dyn if checked_l[k][i]]
        switched = _simulate(w, held, watch, n_steps, d_sim_perc, lazy)
        if switched:
            switched_at += [(k, i, d) for i, d in switched.items()]
        tested += [(k, item[0], item[6]) for item in watch if item[6]]
        w.read_raw(dyn, raw_p, raw_v, raw_b)
    poses = np.empty((K, M, 7))
    vel = np.zeros((K, M, 6))
    aabbs = np.empty((K, M, 2, 3))
    st = ~dyn_mask
    if st.any():  # static objects never move: their centre-of-mass poses and boxes from the scene
        sp, sb = w0.static_raw()
        poses[:, st], aabbs[:, st] = sp[st], sb[st]
    poses[:, dyn] = np.array(raw_p).reshape(K, D, 7)
    vel[:, dyn] = np.array(raw_v).reshape(K, D, 6)
    aabbs[:, dyn] = np.array(raw_b).reshape(K, D, 2, 3)
    # largest divergences: from the tests in the loop and, lazily, the test after the last step on
    # the state read back (an object that diverged during the last steps is held, at the
    # perception, as in the loop)
    max_d = np.zeros((K, M))
    if tested:
        kk, ii, dd = zip(*tested)
        max_d[list(kk), list(ii)] = dd
    still = checked.copy()
    for k, i, _ in switched_at:
        still[k, i] = False
        modes_out[k, i] = HELD
    if lazy and n_steps > 0 and still.any():
        d_end = np.where(still, np.linalg.norm(poses[..., :3] - target_com, axis=-1), 0.0)
        np.maximum(max_d, d_end, out=max_d)
        for k in np.flatnonzero((d_end > d_sim_perc).any(axis=1)).tolist():
            late = np.flatnonzero(d_end[k] > d_sim_perc).tolist()
            modes_out[k, late] = HELD
            w = pws[k].world
            _Overrider(w, batch.target[k], batch.target_vel[k], batch.contents[k], n_steps).jump(late)
            p, v, b = w.read_raw(dyn)
            poses[k, dyn] = np.array(p).reshape(D, 7)
            vel[k, dyn] = np.array(v).reshape(D, 6)
            aabbs[k, dyn] = np.array(b).reshape(D, 2, 3)
    for k, i, d in switched_at:
        max_d[k, i] = d
    finite = (np.isfinite(poses).all(axis=(1, 2)) & np.isfinite(vel).all(axis=(1, 2))
              & (np.abs(vel[..., :3]) < MAX_SPEED).all(axis=(1, 2)))
    aabbs[~finite] = np.nan
    poses, vel = w0.link_frame(poses, vel)
    return BatchOutput(poses, vel, modes_out, max_d, aabbs, finite, np.zeros((K, M)))


def _simulate(w: World, held: "_Overrider", watch: list[list], n_steps: int, d_sim_perc: float,
              lazy: bool) -> dict[int, float]:
    """The step loop of one world (the hot path, plain Python). ``watch`` items are updated in
    place; returns the objects that switched to HELD during the loop, with their largest divergence
    (lazily, the test after the last step is left to the caller, on the state read back)."""
    c = w.client
    dt = w.settings.time_step
    get = pb.getBasePositionAndOrientation
    get_vel = pb.getBaseVelocity
    step = pb.stepSimulation
    out: dict[int, float] = {}
    s = 0
    while s < n_steps:
        # step, with no test, up to the next step at which one is due
        stop = min(min(item[5] for item in watch), n_steps) if watch else n_steps
        if lazy and stop > n_steps - LAST_STEPS:
            stop = n_steps  # a test due in the last steps is the test after the last step
        if held.items:
            for t in range(s + 1, stop + 1):
                held.apply(t)
                step(physicsClientId=c)
        else:
            for _ in range(stop - s):
                step(physicsClientId=c)
        s = stop
        if lazy and s == n_steps:
            break  # the caller tests after the last step, on the state it reads back
        switched = None
        for item in watch:
            if item[5] > s:
                continue
            p = get(item[1], physicsClientId=c)[0]
            d = math.sqrt((p[0] - item[2]) ** 2 + (p[1] - item[3]) ** 2 + (p[2] - item[4]) ** 2)
            if d > item[6]:
                item[6] = d
            if d > d_sim_perc:
                switched = switched or []
                switched.append(item)
            elif lazy:
                v = get_vel(item[1], physicsClientId=c)[0]
                speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
                # steps k with d + speed * k dt + A_MAX (k dt)^2 / 2 <= d_sim_perc are safe
                tau = (-speed + math.sqrt(speed * speed + 2.0 * A_MAX * (d_sim_perc - d))) / A_MAX
                item[5] = s + max(1, int(tau / dt))
            else:
                item[5] = s + 1
        if switched:
            held.jump([item[0] for item in switched])
            for item in switched:
                out[item[0]] = item[6]
            watch[:] = [item for item in watch if item not in switched]
    held.apply(n_steps + 1)  # held objects end the update exactly at their target
    return out


def depenetrate(w: World, indices: list[int], rounds: int = 2) -> None:
    """Push objects ``indices`` out of whatever they interpenetrate, along the deepest contact's
    normal (Bullet would otherwise shoot them out with a spurious velocity)."""
    c = w.client
    others = [u for u in w.uids] + ([w.floor_uid] if w.floor_uid >= 0 else [])
    for _ in range(rounds):
        moved = False
        for i in indices:
            uid = w.uids[i]
            worst, normal = 0.0, None
            for o in others:
                if o == uid:
                    continue
                for pt in pb.getClosestPoints(uid, o, 0.0, physicsClientId=c):
                    if pt[8] < worst:  # contact distance, negative when penetrating
                        worst, normal = pt[8], pt[7]  # normal on B, pointing from B to A
            if normal is not None and worst < -1e-4:
                pos, orn = pb.getBasePositionAndOrientation(uid, physicsClientId=c)
                shift = -worst + 1e-4
                pb.resetBasePositionAndOrientation(uid, [pos[k] + normal[k] * shift for k in range(3)], orn,
                                                   physicsClientId=c)
                moved = True
        if not moved:
            break


class _Overrider:
    """Moves held objects at every step (hot path: plain lists, direct pybullet calls).

    Objects held since the start of the update glide from where they were to their target, linearly
    in position and along the shortest arc in orientation, with the matching velocity, so that the
    contact solver moves what they carry or push (a tilted box pours its contents out). Objects that
    become held during the update (a divergence) jump to their target at once and take their contents
    with them rigidly, rotation included, as Algorithm 1 does.
    """

    def __init__(self, w: World, target: np.ndarray, target_vel: np.ndarray, contents: np.ndarray,
                 n_steps: int):
        self.w = w
        self.target = target
        self.tvel = target_vel
        self.contents = contents
        self.n = max(1, int(n_steps))
        self.items: list[tuple] = []  # (body id, per-step com positions, per-step orientations, lin, ang)

    def glide(self, indices: list[int]) -> None:
        """Add objects held from the start of the update: interpolate from their present pose."""
        if not indices:
            return
        w, n = self.w, self.n
        start = w.get_poses(indices)
        end = self.target[indices]
        frac = np.arange(n + 1) / n  # pose before step s is at frac[s - 1]; after the last, at 1
        dq = quat_multiply(end[:, 3:], quat_conjugate(start[:, 3:]))
        rv = quat_to_rotvec(dq)  # (len, 3) shortest rotation from start to end
        dt = n * w.settings.time_step
        for k, i in enumerate(indices):
            pos = start[k, :3] + frac[:, None] * (end[k, :3] - start[k, :3])
            orn = quat_multiply(quat_from_rotvec(frac[:, None] * rv[k]), start[k, 3:])
            com = w.com_positions(np.concatenate([pos, orn], axis=1), [i] * (n + 1))
            lin = ((end[k, :3] - start[k, :3]) / dt).tolist()
            ang = (rv[k] / dt).tolist()
            self.items.append((w.uids[i], com.tolist(), orn.tolist(), lin, ang))

    def jump(self, indices: list[int]) -> None:
        """Add objects that became held now: move them (and their contents) to the target at once."""
        w = self.w
        before = w.get_poses(indices)
        w.set_poses(self.target[indices], indices)
        w.set_velocities(self.tvel[indices], indices)
        for k, i in enumerate(indices):
            ch = [int(j) for j in np.flatnonzero(self.contents[:, i]) if j not in indices]
            if ch:
                w.set_poses(carry_pose(w.get_poses(ch), before[k], self.target[i]), ch)
                cv = w.get_velocities(ch)
                cv[:, :3] = self.tvel[i, :3]
                w.set_velocities(cv, ch)
        com = w.com_positions(self.target[indices], indices)
        for k, i in enumerate(indices):
            v = self.tvel[i].tolist()
            pos = [com[k].tolist()] * (self.n + 1)
            orn = [self.target[i, 3:].tolist()] * (self.n + 1)
            self.items.append((w.uids[i], pos, orn, v[:3], v[3:]))

    def apply(self, s: int) -> None:
        """Place the held objects where they are before step ``s`` (1-based; ``n + 1``: the end)."""
        c = self.w.client
        reset, reset_vel = pb.resetBasePositionAndOrientation, pb.resetBaseVelocity
        k = min(s - 1, self.n)
        for uid, pos, orn, lin, ang in self.items:
            reset(uid, pos[k], orn[k], physicsClientId=c)
            reset_vel(uid, lin, ang, physicsClientId=c)
