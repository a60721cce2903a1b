import pybullet as pb
import pytest

from physics.bodies import DEFAULT_PRIMITIVE_MASS, apply_dynamics, create_body
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
