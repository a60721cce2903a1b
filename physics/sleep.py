"""Sleeping bodies: a body at rest can be put to sleep, and then costs almost nothing to step.

Bullet wakes a sleeping body when an awake body touches it, but not when it is reset, nor when
what it rests on is taken away: whoever moves bodies wakes them and what they touched
(:func:`touching`, read before the move). Needs :attr:`PhysicsSettings.sleeping` (otherwise a body
never sleeps). Every function takes a :class:`~physics.world.World` and object indices.
"""
from __future__ import annotations

import pybullet as pb

from .world import World


def wake(world: World, indices) -> None:
    """Wake objects ``indices`` (needed after a reset when :attr:`PhysicsSettings.sleeping`).
    Bullet clears a woken body's velocity in the next step: a body loaded with a velocity while
    asleep must be given it again after that step (see :func:`estimator.worlds.propagate.propagate_batch`)."""
    c = world.client
    change = pb.changeDynamics
    for i in indices:
        if not world.is_parked(i):
            change(world.uids[i], -1, activationState=pb.ACTIVATION_STATE_WAKE_UP, physicsClientId=c)


def sleep(world: World, indices) -> None:
    """Put objects ``indices`` to sleep (their velocities become zero): stepping skips them until
    an awake body touches them or :func:`wake` is called. Needs :attr:`PhysicsSettings.sleeping`."""
    c = world.client
    change = pb.changeDynamics
    for i in indices:
        change(world.uids[i], -1, activationState=pb.ACTIVATION_STATE_SLEEP, physicsClientId=c)


def asleep(world: World, indices) -> list[int]:
    """Those of objects ``indices`` that are asleep (a sleeping body reads back exactly zero
    velocity; so does an awake one at exact rest, which is then taken as asleep)."""
    c = world.client
    get = pb.getBaseVelocity
    return [i for i in indices if get(world.uids[i], physicsClientId=c) == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))]


def touching(world: World, indices) -> list[int]:
    """Objects (indices, sorted) in contact with any of ``indices`` after the last step, the
    floor and ``indices`` themselves excluded (contacts of sleeping bodies are kept)."""
    c = world.client
    found: set[int] = set()
    for i in indices:
        for pt in pb.getContactPoints(bodyA=world.uids[i], physicsClientId=c):
            j = world.index_of_uid(pt[2])
            if j >= 0:
                found.add(j)
    return sorted(found.difference(indices))


def near(world: World, indices, margin: float = 0.01) -> list[int]:
    """Objects (indices, sorted) whose bounding boxes come within ``margin`` (m) of those of objects
    ``indices`` (all their links) as they are now (the broadphase's answer; ``indices`` themselves
    and the floor excluded): what a body just moved may touch once stepped, when no contact of it is
    known yet."""
    c = world.client
    found: set[int] = set()
    for i in indices:
        uid = world.uids[i]
        lo, hi = pb.getAABB(uid, -1, physicsClientId=c)
        for link in range(pb.getNumJoints(uid, physicsClientId=c)):
            a, b = pb.getAABB(uid, link, physicsClientId=c)
            lo, hi = [min(x, y) for x, y in zip(lo, a)], [max(x, y) for x, y in zip(hi, b)]
        lo = [x - margin for x in lo]
        hi = [x + margin for x in hi]
        for o, _ in pb.getOverlappingObjects(lo, hi, physicsClientId=c) or ():
            j = world.index_of_uid(o)
            if j >= 0:
                found.add(j)
    return sorted(found.difference(indices))
