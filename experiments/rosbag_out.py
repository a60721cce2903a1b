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
        stamp = T["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        header = T["std_msgs/msg/Header"](stamp=stamp, frame_id=self.world_frame)
        transforms = []
        for oid, ob in estimate["objects"].items():
            p, q = ob["position"], ob.get("orientation") or [0.0, 0.0, 0.0, 1.0]
            tr = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
            transforms.append(T["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=f"estimate/{oid}",
                                                                      transform=tr))
        tf = T[TF_TYPE](transforms=transforms)
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
