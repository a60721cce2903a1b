"""Bodies of a scene's objects in a pybullet client: URDFs (retried once, collision-only if asked),
primitives and open containers (their collision shapes shared between copies of a scene), and their
physical parameters (and the rolling friction Bullet must be given to realise a stated one,
:func:`bullet_rolling_friction`). Every call names its client."""
from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from .errors import SceneError
from .scene import ObjectSpec
from .urdf import collision_only_urdf

DEFAULT_PRIMITIVE_MASS = 0.1
DEFAULT_URDF_MASS = 0.5


def create_body(client: int, spec: ObjectSpec, position: list[float], shapes: dict[int, int], index: int, *,
                collision_only: bool = False, source: str | None = None) -> int:
    """Create object ``index`` of a scene (``spec``) at ``position`` (m, client frame) and its scene
    orientation; returns its body id. ``shapes`` caches primitive collision shapes by object index
    (copies of a scene in one client share them). A URDF that pybullet cannot load is a
    :class:`SceneError` naming ``source`` and the field."""
    c = client
    pos = position
    orn = list(spec.orientation)
    if spec.shape == "urdf":
        uid = -1
        path = collision_only_urdf(spec.urdf) if collision_only else spec.urdf
        for _attempt in range(2):  # a transient failure (file being written) gets one retry
            try:
                uid = pb.loadURDF(path, pos, orn, useFixedBase=spec.static,
                                  globalScaling=spec.scale, physicsClientId=c)
                break
            except pb.error:
                uid = -1
        if uid < 0:
            raise SceneError(f"pybullet could not load URDF {spec.urdf}", path=source,
                             field=f"objects[{index}].urdf")
        if spec.static:
            pb.changeDynamics(uid, -1, mass=0.0, physicsClientId=c)
        else:
            mass = spec.mass
            if mass is None and pb.getDynamicsInfo(uid, -1, physicsClientId=c)[0] <= 0:
                mass = DEFAULT_URDF_MASS
            if mass is not None:
                pb.changeDynamics(uid, -1, mass=mass, physicsClientId=c)
    else:
        if index not in shapes:
            shapes[index] = collision_shape(c, spec)
        mass = 0.0 if spec.static else (spec.mass if spec.mass is not None else DEFAULT_PRIMITIVE_MASS)
        uid = pb.createMultiBody(mass, shapes[index], -1, pos, orn, physicsClientId=c)
    apply_dynamics(c, uid, spec.friction, spec.rolling_friction, spec.spinning_friction, spec.restitution)
    return uid


def collision_shape(client: int, spec: ObjectSpec) -> int:
    """A collision shape for a primitive or container ``spec``, frame at the centre of its box."""
    c = client
    if spec.shape == "box":
        return pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.5 * v for v in spec.size],
                                       physicsClientId=c)
    if spec.shape == "sphere":
        return pb.createCollisionShape(pb.GEOM_SPHERE, radius=spec.radius, physicsClientId=c)
    if spec.shape == "cylinder":
        return pb.createCollisionShape(pb.GEOM_CYLINDER, radius=spec.radius, height=spec.height,
                                       physicsClientId=c)
    # open-top container: floor + four walls standing on it, frame at the centre of the outer box
    # (only the floor reaches the bottom: what the container rests on touches one box, not five)
    sx, sy, sz = spec.size
    w = spec.wall
    hw, zw = (sz - w) / 2, w / 2  # walls: half height, centre height
    half = [[sx / 2, sy / 2, w / 2],
            [w / 2, sy / 2, hw], [w / 2, sy / 2, hw],
            [sx / 2 - w, w / 2, hw], [sx / 2 - w, w / 2, hw]]
    centres = [[0, 0, -sz / 2 + w / 2],
               [sx / 2 - w / 2, 0, zw], [-sx / 2 + w / 2, 0, zw],
               [0, sy / 2 - w / 2, zw], [0, -sy / 2 + w / 2, zw]]
    return pb.createCollisionShapeArray([pb.GEOM_BOX] * 5, halfExtents=half,
                                        collisionFramePositions=centres, physicsClientId=c)


def apply_dynamics(client: int, uid: int, friction: float | None, rolling: float | None,
                   spinning: float | None, restitution: float | None, mass: float | None = None) -> None:
    """Set lateral / rolling / spinning friction, restitution and mass (kg) of body ``uid`` in one
    ``changeDynamics`` call (the state one call per kind gives); None keeps one."""
    values = {"lateralFriction": friction, "rollingFriction": rolling, "spinningFriction": spinning,
              "restitution": restitution, "mass": mass}
    kw = {k: float(v) for k, v in values.items() if v is not None}
    if kw:
        pb.changeDynamics(uid, -1, physicsClientId=client, **kw)


def bullet_rolling_friction(stated, support_friction):
    """The rolling friction (m) to give a Bullet body so that it rolls on a support of lateral
    friction ``support_friction`` with the rolling friction ``stated`` (m): the resisting torque
    ``stated`` x normal force, as a scene states it and as MuJoCo realises it, whatever the support.
    Bullet combines two bodies' coefficients as ``rolling_a mu_b + rolling_b mu_a``: a ball of rolling
    friction r rolls twice as far on a support of lateral friction 0.5 as on one of 1.0. For a
    support without rolling friction of its own (the floor, a table, a box: Bullet's default is 0)
    ``stated / support_friction`` gives exactly ``stated``. Arrays broadcast; where the support is
    unknown (NaN) or frictionless, ``stated`` is returned unchanged."""
    stated = np.asarray(stated, dtype=float)
    mu = np.asarray(support_friction, dtype=float)
    ok = np.isfinite(mu) & (mu > 0)
    return np.where(ok, stated / np.where(ok, mu, 1.0), stated)


def support_friction(client: int, uid: int, min_normal_z: float = 0.5) -> float:
    """Lateral friction of the body ``uid`` rests on, from the contacts of the last collision
    detection: of the bodies whose contact normal points up into ``uid`` (z component of the normal
    on the other body above ``min_normal_z``), the one pushing hardest (largest summed normal force);
    NaN when nothing supports it."""
    force: dict[int, float] = {}
    for cp in pb.getContactPoints(bodyA=uid, physicsClientId=client):
        if cp[7][2] > min_normal_z:
            force[cp[2]] = force.get(cp[2], 0.0) + cp[9]
    if not force:
        return math.nan
    other = max(sorted(force), key=lambda u: force[u])
    return float(pb.getDynamicsInfo(other, -1, physicsClientId=client)[1])
