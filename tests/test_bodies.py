import math

import numpy as np
import pybullet as pb
import pytest

from physics.bodies import (
    DEFAULT_PRIMITIVE_MASS,
    apply_dynamics,
    bullet_rolling_friction,
    create_body,
    support_friction,
)
from physics.errors import SceneError
from physics.scene import ObjectSpec


def test_copies_share_a_primitive_shape_and_keep_unset_parameters():
    c = pb.connect(pb.DIRECT)
    try:
        spec = ObjectSpec(id="box", shape="box", size=(0.1, 0.1, 0.1), friction=0.7)
        shapes: dict[int, int] = {}
        a = create_body(c, spec, [0, 0, 1], shapes, 1)
        b = create_body(c, spec, [5, 0, 1], shapes, 1)
        assert list(shapes) == [1] and a != b
        info = pb.getDynamicsInfo(b, -1, physicsClientId=c)
        assert info[0] == pytest.approx(DEFAULT_PRIMITIVE_MASS) and info[1] == pytest.approx(0.7)
        apply_dynamics(c, b, None, None, None, 0.4)  # only the restitution changes
        info = pb.getDynamicsInfo(b, -1, physicsClientId=c)
        assert info[1] == pytest.approx(0.7) and info[5] == pytest.approx(0.4)
        with pytest.raises(SceneError, match=r"objects\[2\]\.urdf"):
            create_body(c, ObjectSpec(id="bad", shape="urdf", urdf="/nonexistent/x.urdf"), [0, 0, 0], shapes, 2,
                        source="scene.yaml")
    finally:
        pb.disconnect(physicsClientId=c)


def _roll_distance(plane_friction: float, rolling: float) -> float:
    """How far (m) a 3 cm ball (rolling friction ``rolling`` as given to Bullet) rolls from 0.4 m/s
    on a plane of lateral friction ``plane_friction`` before it stops."""
    c = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        ground = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[3, 3, 0.1], physicsClientId=c),
                                    basePosition=[0, 0, -0.1], physicsClientId=c)
        ball = pb.createMultiBody(0.05, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.03, physicsClientId=c),
                                  basePosition=[0, 0, 0.03], physicsClientId=c)
        pb.changeDynamics(ground, -1, lateralFriction=plane_friction, physicsClientId=c)
        pb.changeDynamics(ball, -1, rollingFriction=rolling, angularDamping=0.0, linearDamping=0.0, physicsClientId=c)
        pb.resetBaseVelocity(ball, [0.4, 0, 0], [0, 0.4 / 0.03, 0], physicsClientId=c)
        for _ in range(240 * 4):
            pb.stepSimulation(physicsClientId=c)
        return pb.getBasePositionAndOrientation(ball, physicsClientId=c)[0][0]
    finally:
        pb.disconnect(c)


def test_a_stated_rolling_friction_rolls_a_ball_as_far_on_any_support_once_given_for_it():
    """Bullet scales a body's rolling friction by its support's lateral friction: given as stated, a
    ball rolls about twice as far on a support of friction 0.5 as on one of 1.0. Given
    bullet_rolling_friction(stated, support), it rolls the same distance on both, the one a
    resisting torque of stated x normal force gives (v^2 / 2a, a = stated g / (1.4 r) for a solid
    ball rolling without slipping), within the integrator's error."""
    stated = 0.001
    raw = {mu: _roll_distance(mu, stated) for mu in (0.5, 1.0)}
    assert raw[0.5] > 1.8 * raw[1.0]
    given = {mu: _roll_distance(mu, float(bullet_rolling_friction(stated, mu))) for mu in (0.25, 0.5, 1.0)}
    assert max(given.values()) < 1.05 * min(given.values())
    expected = 0.4 ** 2 / (2 * stated * 9.81 / (1.4 * 0.03))
    assert abs(given[1.0] - expected) < 0.15 * expected
    assert bullet_rolling_friction(stated, math.nan) == stated and bullet_rolling_friction(stated, 0.0) == stated
    assert np.allclose(bullet_rolling_friction([0.001, 0.002], [0.5, np.nan]), [0.002, 0.002])


def test_the_support_friction_is_that_of_the_body_underneath_and_nan_in_the_air():
    c = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        ground = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[1, 1, 0.1], physicsClientId=c),
                                    basePosition=[0, 0, -0.1], physicsClientId=c)
        block = pb.createMultiBody(1.0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.1, 0.1, 0.05],
                                                                physicsClientId=c),
                                   basePosition=[0, 0, 0.05], physicsClientId=c)
        ball = pb.createMultiBody(0.05, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.03, physicsClientId=c),
                                  basePosition=[0, 0, 0.13], physicsClientId=c)
        flier = pb.createMultiBody(0.05, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.03, physicsClientId=c),
                                   basePosition=[0.5, 0.5, 0.5], physicsClientId=c)
        pb.changeDynamics(ground, -1, lateralFriction=0.9, physicsClientId=c)
        pb.changeDynamics(block, -1, lateralFriction=0.3, physicsClientId=c)
        for _ in range(30):
            pb.stepSimulation(physicsClientId=c)
        assert support_friction(c, ball) == pytest.approx(0.3)
        assert support_friction(c, block) == pytest.approx(0.9)
        assert math.isnan(support_friction(c, flier))
    finally:
        pb.disconnect(c)
