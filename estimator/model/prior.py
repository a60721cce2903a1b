"""The prior at rest: where the scene's objects come to rest from the poses the scene gives them.

A scene file states where objects are to within a tracker's noise, not a pose they can rest in:
a duck given 10 degrees off the tilt its rounded base rests at rocks when dropped there. Put in K
worlds at once, it rocks in every one of them, and each jitter of the filter (regularisation,
process noise) of a few millimetres moves it without its contacts, which Bullet then makes afresh, and
that gives the swing energy instead of taking it: in 255 of 256 particles the hidden duck tipped
over onto its side, though it stands in the truth, and it stayed awake doing it.
:func:`rest_prior` settles the scene once, in one world with the scene's own parameters, and keeps
for each object the pose it came to rest in when that is within the prior's stated uncertainty
(otherwise the object is somewhere physics does not leave it, held in the air say, and the scene's
pose stands). It also says which of them rest *flat on static bodies alone* (:data:`FLAT_NORMAL`):
such an object moved along its support by the particles' horizontal perturbation is at rest where
it lands (:func:`~estimator.model.regularisation.placed_at_rest`), and its worlds need not settle
it. Array shapes: M objects, poses ``(M, 7)``: metres, quaternions x, y, z, w.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pybullet as pb

from physics.scene import Scene
from physics.settings import PhysicsSettings
from physics.transforms import quat_angle
from physics.world import World

from ..worlds.resting import at_rest

WINDOW = 0.05
"""s: the settling is tested for rest over windows of this length (as the ground truth's)."""
MAX_TIME = 2.0
"""s: the most the prior settles; objects still moving then keep the scene's poses."""
FLAT_NORMAL = 0.9995
"""An object rests flat on static bodies when it touches something, and every contact of it at rest
is with a static body (or the floor) whose normal there is within this cosine of the vertical
(1.8 degrees): its friction holds nothing up, so that particles whose frictions differ rest as it does."""
REACH_SIGMAS = 3.0
"""An object takes its rest pose when it is within this many standard deviations of the perception
noise (``NoiseConfig.position_std``, ``orientation_std``) of its given pose
(:class:`~estimator.model.SceneModel`)."""


def _settle(world: World, poses: np.ndarray, indices: list[int]) -> tuple[np.ndarray, bool]:
    """Step ``world`` from ``poses (M, 7)`` until objects ``indices`` are at rest over a :data:`WINDOW`
    (:func:`~estimator.worlds.resting.at_rest`; at most :data:`MAX_TIME`); returns the poses
    ``(M, 7)`` reached and whether they are at rest."""
    world.set_poses(poses)
    world.set_velocities(np.zeros((len(poses), 6)))
    n = max(1, int(round(WINDOW / world.settings.time_step)))
    span = n * world.settings.time_step
    for _ in range(int(round(MAX_TIME / WINDOW))):
        before = world.get_poses(indices)
        world.step(n)
        if at_rest(before, world.get_poses(indices), span):
            return world.get_poses(), True
    return world.get_poses(), False


def _flat(world: World, indices: list[int]) -> list[int]:
    """Of objects ``indices`` at rest in ``world``, those that rest flat on static bodies alone
    (:data:`FLAT_NORMAL`), from the contacts of its last step."""
    flat = []
    for i in indices:
        contacts = pb.getContactPoints(bodyA=world.uids[i], physicsClientId=world.client)
        others = [world.index_of_uid(pt[2]) for pt in contacts]
        # the normal on the other body points from it to this one: up, from a support
        if contacts and all(j != -1 and (j < 0 or world.static[j]) and pt[7][2] >= FLAT_NORMAL
                            for j, pt in zip(others, contacts)):
            flat.append(i)
    return flat


def rest_prior(scene: Scene, poses: np.ndarray, known: np.ndarray, settings: PhysicsSettings,
               reach: float, turn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scene's poses ``poses (M, 7)`` with each known dynamic object (``known (M,)`` bool) at
    the pose it comes to rest in, settled in one world built with ``settings`` and the scene's
    parameters, where that is at most ``reach`` (m) and ``turn`` (rad) from its given pose (the
    world does not let bodies sleep: a reset would not wake them).

    The others keep their given poses, and are out of collision in a second settling so that the
    rest is not what their fall would make it. Returns the poses ``(M, 7)``, which objects took
    their rest pose ``(M,)`` bool (none when the scene did not come to rest within
    :data:`MAX_TIME`) and which of those rest flat on static bodies alone ``(M,)`` bool
    (:data:`FLAT_NORMAL`; nothing of the scene touches them)."""
    poses = np.array(poses, dtype=float)
    out, rested, flat = poses.copy(), np.zeros(len(poses), dtype=bool), np.zeros(len(poses), dtype=bool)
    with World(scene, dataclasses.replace(settings, sleeping=False)) as world:
        todo = [int(i) for i in world.dynamic_indices if known[i]]
        while todo:
            settled, at_rest = _settle(world, poses, todo)
            if not at_rest:
                return out, rested, flat
            near = ((np.linalg.norm(settled[todo, :3] - poses[todo, :3], axis=1) <= reach)
                    & (quat_angle(settled[todo, 3:], poses[todo, 3:]) <= turn))
            if np.all(near):
                out[todo], rested[todo] = settled[todo], True
                flat[_flat(world, todo)] = True  # (the others' clearance is the particles' to check)
                break
            world.set_colliding([i for i, ok in zip(todo, near) if not ok], False)
            todo = [i for i, ok in zip(todo, near) if ok]
    return out, rested, flat
