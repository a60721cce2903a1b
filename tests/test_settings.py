"""Engine settings and the clients made with them: physics.settings."""
import numpy as np
import pybullet as pb

from physics.settings import PhysicsSettings, connect


def _drop_shapes(settings: PhysicsSettings):
    """A sphere, a cylinder and a box dropped on the floor of a client made with ``settings``: the
    client, the bodies and their poses after 120 steps."""
    c, _ = connect(settings, True)
    shapes = [pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.03, physicsClientId=c),
              pb.createCollisionShape(pb.GEOM_CYLINDER, radius=0.03, height=0.1, physicsClientId=c),
              pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.02, 0.03, 0.04], physicsClientId=c)]
    bodies = [pb.createMultiBody(0.2, s, -1, [0.1 * j, 0.02 * j, 0.2 + 0.05 * j], [0.1, 0.2, 0.0, 0.97],
                                 physicsClientId=c) for j, s in enumerate(shapes)]
    for _ in range(120):
        pb.stepSimulation(physicsClientId=c)
    poses = [pb.getBasePositionAndOrientation(b, physicsClientId=c) for b in bodies]
    return c, bodies, poses


def test_a_collision_only_client_is_never_drawn_and_steps_as_any_other():
    """collision_only unloads the client's renderer: a camera image of it shows none of its bodies
    (a default client's shows them), and its physics is the same bit for bit."""
    view = pb.computeViewMatrix([1.0, 0.0, 0.5], [0.1, 0.0, 0.0], [0, 0, 1])
    proj = pb.computeProjectionMatrixFOV(60, 1.0, 0.05, 5.0)
    seen, poses = {}, {}
    for only in (True, False):
        c, bodies, poses[only] = _drop_shapes(PhysicsSettings(collision_only=only))
        try:
            mask = np.asarray(pb.getCameraImage(32, 32, view, proj, physicsClientId=c)[4])
            seen[only] = set(bodies) & set(np.unique(mask).tolist())
        finally:
            pb.disconnect(physicsClientId=c)
    assert seen[False] and not seen[True]
    assert poses[True] == poses[False]
