"""Advance one particle's world through one update: Algorithm 1 of the physics reasoner.

This is the hot path, run in the worker that owns the world. It takes and returns plain arrays so that
worker processes exchange only numpy data. One call simulates ``n_steps`` fixed steps and, at every
step:

* HELD objects are overridden with their target pose and velocity (the perception, a tracked hand, or
  where they were last seen), and their contents are carried with them, rotation included;
* FREE objects that are checked (perceived, dynamic) and whose simulated position diverges from the
  perceived one by more than ``d_sim_perc`` switch to HELD (they are not physically plausible: an agent
  must be moving them) and are overridden from that step on.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from actions.modes import FREE, HELD
from physics.transforms import carry_pose
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
    """

    poses: np.ndarray
    velocities: np.ndarray
    params: np.ndarray
    modes: np.ndarray
    check: np.ndarray
    target: np.ndarray
    target_vel: np.ndarray
    contents: np.ndarray


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


def propagate(pw: ParticleWorld, inp: StepInput, n_steps: int, d_sim_perc: float,
              switch_on_divergence: bool = True) -> StepOutput:
    """Run Algorithm 1 for ``n_steps`` steps in ``pw``'s world from the state in ``inp``."""
    w = pw.world
    c = w.client
    dyn = [int(i) for i in w.dynamic_indices]
    pw.apply_params(inp.params)
    w.set_poses(inp.poses[dyn], dyn)
    w.set_velocities(inp.velocities[dyn], dyn)
    modes = inp.modes.copy()
    max_d2 = np.zeros(len(modes))
    target = inp.target
    tvel_rows = inp.target_vel.tolist()
    contents = inp.contents
    held = [i for i in dyn if modes[i] == HELD]
    # checked objects as plain tuples (index, body id, target of its centre of mass): the per-step
    # test is the hot path and stays in plain Python
    checked = [i for i in dyn if inp.check[i] and modes[i] == FREE]
    com = w.com_positions(target[checked], checked) if checked else np.zeros((0, 3))
    watch = [(i, w.uids[i], float(x), float(y), float(z)) for i, (x, y, z) in zip(checked, com.tolist())]
    best = [0.0] * len(watch)
    limit = d_sim_perc * d_sim_perc
    get = pb.getBasePositionAndOrientation
    step = pb.stepSimulation
    for _ in range(int(n_steps)):
        if held:
            _override(w, held, target, tvel_rows, contents)
        step(physicsClientId=c)
        if not watch:
            continue
        switched = None
        for k, (i, uid, tx, ty, tz) in enumerate(watch):
            p = get(uid, physicsClientId=c)[0]
            d2 = (p[0] - tx) ** 2 + (p[1] - ty) ** 2 + (p[2] - tz) ** 2
            if d2 > best[k]:
                best[k] = d2
            if d2 > limit and switch_on_divergence:
                switched = switched or []
                switched.append(k)
        if switched:
            moved = [watch[k][0] for k in switched]
            for i in moved:
                modes[i] = HELD
            held = held + moved
            _override(w, moved, target, tvel_rows, contents)
            keep = [k for k in range(len(watch)) if k not in switched]
            for k in switched:
                max_d2[watch[k][0]] = best[k]
            watch = [watch[k] for k in keep]
            best = [best[k] for k in keep]
    for k, item in enumerate(watch):
        max_d2[item[0]] = best[k]
    if held:  # held objects end the update exactly at their target
        _override(w, held, target, tvel_rows, contents)
    poses = inp.poses.copy()
    vel = inp.velocities.copy()
    poses[dyn] = w.get_poses(dyn)
    vel[dyn] = w.get_velocities(dyn)
    finite = bool(np.all(np.isfinite(poses)) and np.all(np.isfinite(vel))
                  and np.all(np.abs(vel[:, :3]) < MAX_SPEED))
    aabbs = w.aabbs() if finite else np.full((len(modes), 2, 3), np.nan)
    return StepOutput(poses, vel, modes, np.sqrt(max_d2), aabbs, finite)


def _override(w: World, held: list[int], target: np.ndarray, tvel_rows: list, contents: np.ndarray) -> None:
    """Set held objects to their targets and carry their contents rigidly."""
    children = [np.flatnonzero(contents[:, i]) for i in held]
    movers = [i for i, ch in zip(held, children) if len(ch)]
    if movers:
        before = w.get_poses(movers)
    w.set_poses(target[held], held)
    w.set_velocities(np.array([tvel_rows[i] for i in held]), held)
    for k, i in enumerate(movers):
        ch = [int(j) for j in np.flatnonzero(contents[:, i]) if j not in held]
        if not ch:
            continue
        child_poses = w.get_poses(ch)
        w.set_poses(carry_pose(child_poses, before[k], target[i]), ch)
        cv = w.get_velocities(ch)
        cv[:, :3] = tvel_rows[i][:3]
        w.set_velocities(cv, ch)
