"""Estimates written back into a ROS bag (``scene-estimator run --bag-out``), to replay beside the input.

Each reasoning step becomes one ``tf2_msgs/TFMessage`` on ``/tf`` (one transform per object: parent
the world frame, child ``estimate/<object id>``, the consensus pose in metres and quaternion x, y, z, w)
and one ``std_msgs/String`` on ``/scene_estimator/estimate`` whose data is the estimate line (JSON),
both stamped ``t0 + t`` (the input bag's start plus the estimate's time in seconds). A path ending in
``.bag`` is written as a ROS 1 bag, any other path as a ROS 2 bag folder (sqlite3).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from physics.errors import ObservationError

ESTIMATE_TOPIC = "/scene_estimator/estimate"
TF_TOPIC = "/tf"
TF_TYPE = "tf2_msgs/msg/TFMessage"
STRING_TYPE = "std_msgs/msg/String"


def header(types, stamp_ns: int, frame_id: str):
    """A ``std_msgs/Header`` stamped ``stamp_ns`` (ns) in ``frame_id``, from a typestore's ``types``."""
    return types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000),
        frame_id=frame_id)


def transform_stamped(types, stamp_ns: int, parent: str, child: str, position, orientation):
    """A ``geometry_msgs/TransformStamped`` ``parent -> child`` at ``position (3,)`` (m) and
    ``orientation (4,)`` (x, y, z, w)."""
    p, q = [float(v) for v in position], [float(v) for v in orientation]
    return types["geometry_msgs/msg/TransformStamped"](
        header=header(types, stamp_ns, parent), child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
            rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))


def pose_stamped(types, stamp_ns: int, frame_id: str, position, orientation):
    """A ``geometry_msgs/PoseStamped`` in ``frame_id`` at ``position (3,)`` (m), ``orientation (4,)``."""
    p, q = [float(v) for v in position], [float(v) for v in orientation]
    return types["geometry_msgs/msg/PoseStamped"](
        header=header(types, stamp_ns, frame_id),
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))


class BagEstimateWriter:
    """Write estimate lines (the dicts of ``Belief.to_json()``) to a bag; a context manager.

    Args:
        path: output bag (``.bag``: ROS 1 file; otherwise: ROS 2 folder). Must not exist yet.
        world_frame: parent frame of the ``estimate/<id>`` frames.
        t0_ns: stamp (ns) of ``t = 0``.
    """

    def __init__(self, path: str, world_frame: str = "world", t0_ns: int = 0):
        from rosbags.typesys import Stores, get_typestore

        self.path = str(path)
        self.world_frame = world_frame
        self.t0_ns = int(t0_ns)
        self.ros1 = self.path.endswith(".bag")
        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        if os.path.exists(self.path):
            raise ObservationError("output bag already exists (remove it or choose another path)", path=self.path)
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise ObservationError(f"folder {parent} does not exist", path=self.path)
        if self.ros1:
            from rosbags.rosbag1 import Writer
            self._writer = Writer(Path(self.path))
        else:
            from rosbags.rosbag2 import Writer
            self._writer = Writer(Path(self.path), version=8)
        self._writer.open()
        self._tf = self._writer.add_connection(TF_TOPIC, TF_TYPE, typestore=self.typestore)
        self._str = self._writer.add_connection(ESTIMATE_TOPIC, STRING_TYPE, typestore=self.typestore)
        self.written = 0

    def _serialize(self, msg, msgtype: str):
        if self.ros1:
            return self.typestore.serialize_ros1(msg, msgtype)
        return self.typestore.serialize_cdr(msg, msgtype)

    def write(self, estimate: dict) -> None:
        """Write one estimate line (``{"t", "objects": {id: {"position", "orientation", ...}}, ...}``)."""
        T = self.typestore.types
        stamp_ns = self.t0_ns + int(round(float(estimate["t"]) * 1e9))
        tf = T[TF_TYPE](transforms=[
            transform_stamped(T, stamp_ns, self.world_frame, f"estimate/{oid}", ob["position"],
                              ob.get("orientation") or [0.0, 0.0, 0.0, 1.0])
            for oid, ob in estimate["objects"].items()])
        self._writer.write(self._tf, stamp_ns, self._serialize(tf, TF_TYPE))
        text = T[STRING_TYPE](data=json.dumps(estimate))
        self._writer.write(self._str, stamp_ns, self._serialize(text, STRING_TYPE))
        self.written += 1

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> "BagEstimateWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
