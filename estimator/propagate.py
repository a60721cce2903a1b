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
    finite (bool): False if the simulation produced NaN or a runaway velocity."""

    poses: np.ndarray
    velocities: np.ndarray
    modes: np.ndarray
    max_divergence: np.ndarray
    aabbs: np.ndarray
    finite: bool


class ParticleWorld:
    """A persistent world for one particle slot, remembering the parameters last applied."""

    def __init__(self, world: World):
        self.world = world
        self.dynamic = [int(i) for i in world.dynamic_indices]
        self._params: np.ndarray | None = None

    def apply_params(self, params: np.ndarray) -> None:
        if self._params is not None and np.array_equal(params, self._params):
            return
        w = self.world
        for i in w.dynamic_indices:
            row = params[i]
            if self._params is not None and np.array_equal(row, self._params[i]):
                continue
            w.set_dynamics(int(i), lateral_friction=row[0], rolling_friction=row[1],
                           spinning_friction=row[2], restitution=row[3], mass=row[4])
        self._params = params.copy()


MAX_SPEED = 50.0  # m/s: anything faster is a simulation that exploded


A_MAX = 2.0 * 9.81
"""Bound on an object's acceleration (m/s^2) between two divergence tests when checks are lazy."""


def propagate(pw: ParticleWorld, inp: StepInput, n_steps: int, d_sim_perc: float,
              lazy: bool = False) -> StepOutput:
    """Run Algorithm 1 for ``n_steps`` steps in ``pw``'s world from the state in ``inp``.

    With ``lazy=False`` the divergence of every free perceived object is tested after every step, as
    the paper does. With ``lazy=True`` an object is tested again only at the first step at which,
    starting from its present divergence ``d`` and speed ``v`` and accelerating at most at
    :data:`A_MAX`, it could have crossed ``d_sim_perc`` (and after the last step): exact for objects
    moving freely or resting, late by a few steps only when something hits an object hard.
    """
    w = pw.world
    c = w.client
    dyn = pw.dynamic
    dt = w.settings.time_step
    n_steps = int(n_steps)
    pw.apply_params(inp.params)
    reset = dyn if inp.reset is None else [i for i in dyn if inp.reset[i]]
    if reset:
        w.set_poses(inp.poses[reset], reset)
        w.set_velocities(inp.velocities[reset], reset)
    if inp.depenetrate.any():
        depenetrate(w, [i for i in dyn if inp.depenetrate[i]])
    modes = inp.modes.copy()
    max_d = np.zeros(len(modes))
    target = inp.target
    held = _Overrider(w, target, inp.target_vel, inp.contents, n_steps)
    held.glide([i for i in dyn if modes[i] == HELD])
    # watched objects as plain lists [index, body id, target of its centre of mass, next step to test,
    # largest divergence seen]: the per-step test is the hot path and stays in plain Python
    checked = [i for i in dyn if inp.check[i] and modes[i] == FREE]
    com = w.com_positions(target[checked], checked) if checked else np.zeros((0, 3))
    watch = [[i, w.uids[i], x, y, z, 1, 0.0] for i, (x, y, z) in zip(checked, com.tolist())]
    if lazy and watch:  # the first test is due when the starting state could have diverged
        d0 = np.linalg.norm(w.com_positions(inp.poses[checked], checked) - com, axis=1)
        v0 = np.linalg.norm(inp.velocities[checked, :3], axis=1)
        for item, d, v in zip(watch, d0.tolist(), v0.tolist()):
            if d < d_sim_perc:
                tau = (-v + math.sqrt(v * v + 2.0 * A_MAX * (d_sim_perc - d))) / A_MAX
                item[5] = max(1, int(tau / dt))
    get = pb.getBasePositionAndOrientation
    get_vel = pb.getBaseVelocity
    step = pb.stepSimulation
    next_due = min((item[5] for item in watch), default=n_steps)
    # lazily, the test after the last step uses the state read back at the end (no extra calls)
    last_in_loop = n_steps if not lazy else n_steps + 1
    for s in range(1, n_steps + 1):
        if held.items:
            held.apply(s)
        step(physicsClientId=c)
        if not watch or (s < next_due and s < last_in_loop):
            continue
        switched = None
        for item in watch:
            if item[5] > s and s < last_in_loop:
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
            moved = [item[0] for item in switched]
            for i in moved:
                modes[i] = HELD
            held.jump(moved)
            for item in switched:
                max_d[item[0]] = item[6]
            watch = [item for item in watch if item not in switched]
        next_due = min((item[5] for item in watch), default=n_steps)
    held.apply(n_steps + 1)  # held objects end the update exactly at their target
    poses, vel, aabbs = w.read_state()
    if lazy and watch and n_steps > 0:
        idx = [item[0] for item in watch]
        d_end = np.linalg.norm(w.com_positions(poses[idx], idx) - np.array([item[2:5] for item in watch]), axis=1)
        for item, d in zip(watch, d_end.tolist()):
            item[6] = max(item[6], d)
        late = [item[0] for item, d in zip(watch, d_end.tolist()) if d > d_sim_perc]
        if late:  # diverged during the last steps: held, at the perception, as in the loop
            for i in late:
                modes[i] = HELD
            held.jump(late)
            poses, vel, aabbs = w.read_state()
    for item in watch:
        max_d[item[0]] = item[6]
    finite = bool(np.isfinite(poses).all() and np.isfinite(vel).all() and (np.abs(vel[:, :3]) < MAX_SPEED).all())
    if not finite:
        aabbs = np.full((len(modes), 2, 3), np.nan)
    return StepOutput(poses, vel, modes, max_d, aabbs, finite)


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
