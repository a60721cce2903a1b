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
    check = inp.check.copy()
    check &= ~w.static
    max_div = np.zeros(len(modes))
    target = inp.target
    tvel_rows = inp.target_vel.tolist()
    contents = inp.contents
    uids = w.uids
    get = pb.getBasePositionAndOrientation
    has_offset = w._has_offset
    for _ in range(int(n_steps)):
        held = [i for i in dyn if modes[i] == HELD]
        if held:
            _override(w, held, target, tvel_rows, contents)
        pb.stepSimulation(physicsClientId=c)
        checked = [i for i in dyn if check[i] and modes[i] == FREE]
        if not checked:
            continue
        if has_offset:
            pos = w.get_poses(checked)[:, :3]
        else:
            pos = np.array([get(uids[i], physicsClientId=c)[0] for i in checked])
        d = np.linalg.norm(pos - target[checked, :3], axis=1)
        idx = np.asarray(checked)
        max_div[idx] = np.maximum(max_div[idx], d)
        if switch_on_divergence:
            bad = idx[d > d_sim_perc]
            if len(bad):
                modes[bad] = HELD
                _override(w, [int(i) for i in bad], target, tvel_rows, contents)
    held = [i for i in dyn if modes[i] == HELD]
    if held:  # held objects end the update exactly at their target
        _override(w, held, target, tvel_rows, contents)
    poses = inp.poses.copy()
    vel = inp.velocities.copy()
    poses[dyn] = w.get_poses(dyn)
    vel[dyn] = w.get_velocities(dyn)
    finite = bool(np.all(np.isfinite(poses)) and np.all(np.isfinite(vel))
                  and np.all(np.abs(vel[:, :3]) < MAX_SPEED))
    aabbs = w.aabbs() if finite else np.full((len(modes), 2, 3), np.nan)
    return StepOutput(poses, vel, modes, max_div, aabbs, finite)


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
