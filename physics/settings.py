"""Engine settings of a pybullet world, and a DIRECT client set up with them."""
from __future__ import annotations

import math
from dataclasses import dataclass

import pybullet as pb

FLOOR_FRICTION = 0.5
"""Lateral friction of the floor plane (Bullet's default for a body, stated here because the rolling
friction a body realises on the floor depends on it: :func:`physics.bodies.bullet_rolling_friction`)."""

RENDERER_PLUGIN = "tinyRendererPlugin"
"""The name of pybullet's built-in software renderer, a plugin every DIRECT client starts with
(``loadPlugin`` of a loaded plugin returns its id)."""


@dataclass(frozen=True)
class PhysicsSettings:
    """Engine settings of a world.

    ``time_step`` is the fixed step (s); ``solver_iterations`` Bullet's constraint-solver iterations,
    ``solver_residual_threshold`` the residual at which the solver stops earlier (pybullet's default
    1e-7; the particle worlds use :data:`estimator.config.SOLVER_RESIDUAL`, 1e-6: Bullet's residual
    is the sum of the squared velocity corrections of a sweep, (m/s)^2);
    ``deterministic_pairs`` sorts overlapping pairs so that two identically built worlds agree bit
    for bit. ``sleeping`` lets bodies be put to sleep (:func:`physics.sleep.sleep`; Bullet's own
    deactivation too): a sleeping body costs almost nothing to step and wakes when an awake body
    touches it, but NOT when it is reset, so whoever resets bodies must wake them
    (:func:`physics.sleep.wake`; ``False``, the default, never lets a body sleep). ``collision_only`` loads
    URDFs without their visual meshes and textures (:mod:`physics.urdf`), which physics never uses
    (a world whose visual shapes are read, for drawing, keeps them: the default), and unloads the
    client's TinyRenderer plugin: such a world is never drawn (its camera images show none of its
    bodies), and every body made in a client with the renderer gets a triangle mesh of its shapes
    made for drawing, which tripled the cost of making a sphere or a cylinder (0.5 ms -> 0.15 ms
    measured here; :func:`connect`).
    """

    time_step: float = 1.0 / 240.0
    gravity: float = -9.81
    solver_iterations: int = 50
    solver_residual_threshold: float = 1e-7
    deterministic_pairs: bool = True
    sleeping: bool = False
    collision_only: bool = False

    def __post_init__(self):
        if not (self.time_step > 0 and math.isfinite(self.time_step)):
            raise ValueError(f"time_step must be > 0, got {self.time_step}")
        if self.solver_iterations < 1:
            raise ValueError(f"solver_iterations must be >= 1, got {self.solver_iterations}")
        if not self.solver_residual_threshold > 0:
            raise ValueError(f"solver_residual_threshold must be > 0, got {self.solver_residual_threshold}")


def connect(settings: PhysicsSettings, floor: bool) -> tuple[int, int]:
    """A new DIRECT pybullet client set up with ``settings``; returns ``(client, floor body id)``
    (``-1`` without a floor). The caller disconnects it."""
    c = pb.connect(pb.DIRECT)
    if c < 0:
        raise RuntimeError("could not start a pybullet DIRECT client")
    if settings.collision_only:  # never drawn: no mesh made for drawing each body (PhysicsSettings)
        pb.unloadPlugin(pb.loadPlugin(RENDERER_PLUGIN, physicsClientId=c), physicsClientId=c)
    pb.setGravity(0, 0, settings.gravity, physicsClientId=c)
    pb.setPhysicsEngineParameter(fixedTimeStep=settings.time_step, numSolverIterations=settings.solver_iterations,
                                 solverResidualThreshold=settings.solver_residual_threshold,
                                 deterministicOverlappingPairs=int(settings.deterministic_pairs),
                                 physicsClientId=c)
    floor_uid = -1
    if floor:
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        floor_uid = pb.createMultiBody(0, plane, physicsClientId=c)
        pb.changeDynamics(floor_uid, -1, lateralFriction=FLOOR_FRICTION, physicsClientId=c)
    return c, floor_uid
