"""Playing an observation stream into a live ROS graph, as a robot's perception would publish it: the
tests of the ROS node and its latency benchmark use it (needs rospy: pass
:func:`~experiments.ros.rospy_env.import_ros`'s modules).

Per frame, all stamped ``start + t``:

* ``/tf``: ``world -> camera_link``, a camera that moves (:func:`camera_pose`), and
  ``camera_link -> <id>_tag`` for every detected object (its pose seen from that camera);
  ``world -> hand_<n>`` for every tracked hand;
* ``/tracker/<id>``: ``geometry_msgs/PoseStamped`` in ``table_link`` for the objects in ``tracked``
  (a second source of the same objects, fused with the tags);
* ``/tf_static`` (latched, once): ``world -> table_link``.

:func:`topics_for` is the topics file that reads them back.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Iterable

import numpy as np

from estimator.observations import Frame
from physics.transforms import pose_compose, pose_inverse, quat_from_axis_angle, quat_multiply

WORLD_TABLE = np.array([0.0, 0.0, 0.6, *quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.3)])
TAG_STD = 0.004
TRACKER_STD = 0.006


def camera_pose(t: float) -> np.ndarray:
    """The moving camera in the world at ``t`` (s): it sweeps sideways and pans while it looks at the table."""
    q = quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.pi + 0.2 * math.sin(0.7 * t)),
                      quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.5))
    return np.array([1.1, 0.3 * math.sin(0.5 * t), 1.2, *q])


def hand_frame(name: str) -> str:
    return "hand_" + "".join(c if c.isalnum() else "_" for c in name)


def topics_for(seen: Iterable[str], tracked: Iterable[str], hands: Iterable[str] = (),
               world_frame: str = "world", window: float = 0.005, reorder: float = 0.01) -> dict:
    """The topics file (as a dict) that reads what :class:`Player` publishes."""
    return {"world_frame": world_frame, "window": window, "reorder": reorder,
            "sources": [{"topic": "/tf", "type": "tf", "objects": {f"{oid}_tag": oid for oid in seen},
                         "position_std": TAG_STD}]
            + [{"topic": f"/tracker/{oid}", "type": "pose", "object": oid, "position_std": TRACKER_STD}
               for oid in tracked],
            "hands": {hand_frame(h): h for h in hands}}


def _tf(ros, stamp, parent: str, child: str, pose: np.ndarray):
    gm = ros.geometry_msgs
    t = gm.TransformStamped()
    t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, parent, child
    t.transform.translation = gm.Vector3(*[float(v) for v in pose[:3]])
    t.transform.rotation = gm.Quaternion(*[float(v) for v in pose[3:]])
    return t


def pose_stamped(ros, stamp, frame_id: str, pose) -> object:
    gm = ros.geometry_msgs
    msg = gm.PoseStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.pose.position = gm.Point(*[float(v) for v in pose[:3]])
    msg.pose.orientation = gm.Quaternion(*[float(v) for v in pose[3:]])
    return msg


class Player:
    """Publishers of the module docstring's topics. ``tracked``: object ids that also get a
    PoseStamped topic. Call :meth:`wait_for` to wait for a subscriber, then :meth:`play`."""

    def __init__(self, ros, tracked: Iterable[str] = (), world_frame: str = "world"):
        rospy = ros.rospy
        self.ros, self.world = ros, world_frame
        self.tf = rospy.Publisher("/tf", ros.tf2_msgs.TFMessage, queue_size=100)
        self.tf_static = rospy.Publisher("/tf_static", ros.tf2_msgs.TFMessage, queue_size=10, latch=True)
        self.tracked = {oid: rospy.Publisher(f"/tracker/{oid}", ros.geometry_msgs.PoseStamped, queue_size=100)
                        for oid in tracked}
        self.sent: dict[int, float] = {}  # stamp (ns) -> when its messages were published (time.monotonic)

    def wait_for(self, timeout: float = 30.0) -> None:
        """Wait until every publisher has a subscriber (the node connected), up to ``timeout`` s."""
        deadline = time.monotonic() + timeout
        pubs = [self.tf, *self.tracked.values()]
        while any(p.get_num_connections() == 0 for p in pubs):
            if time.monotonic() > deadline:
                raise TimeoutError("no subscriber on " + ", ".join(p.name for p in pubs if not p.get_num_connections()))
            time.sleep(0.05)

    def publish_static(self, stamp) -> None:
        self.tf_static.publish(self.ros.tf2_msgs.TFMessage([_tf(self.ros, stamp, self.world, "table_link",
                                                                WORLD_TABLE)]))

    def publish(self, frame: Frame, stamp_ns: int) -> None:
        """The messages of one frame, stamped ``stamp_ns``."""
        ros = self.ros
        stamp = ros.rospy.Time(secs=stamp_ns // 1_000_000_000, nsecs=stamp_ns % 1_000_000_000)
        cam = camera_pose(frame.t)
        cam_inv, table_inv = pose_inverse(cam), pose_inverse(WORLD_TABLE)
        transforms = [_tf(ros, stamp, self.world, "camera_link", cam)]
        for oid, det in frame.objects.items():
            pose = np.concatenate([det.position, det.orientation if det.orientation is not None else [0, 0, 0, 1.0]])
            transforms.append(_tf(ros, stamp, "camera_link", f"{oid}_tag", pose_compose(cam_inv, pose)))
        for name, pos in frame.hands.items():
            transforms.append(_tf(ros, stamp, self.world, hand_frame(name), np.array([*pos, 0, 0, 0, 1.0])))
        self.tf.publish(ros.tf2_msgs.TFMessage(transforms))
        for oid, det in frame.objects.items():
            if oid in self.tracked:
                pose = np.concatenate([det.position, det.orientation if det.orientation is not None
                                       else [0, 0, 0, 1.0]])
                self.tracked[oid].publish(pose_stamped(ros, stamp, "table_link", pose_compose(table_inv, pose)))
        self.sent[stamp_ns] = time.monotonic()

    def play(self, frames: list[Frame], start_ns: int, speed: float = 1.0,
             between: Callable[[int, Frame], None] | None = None) -> None:
        """Publish ``frames`` at their own pace (frame ``t`` at wall time ``start + (t - t_first) / speed``),
        stamped ``start_ns + t``; ``between(k, frame)`` is called after frame ``k`` is published."""
        t_first = frames[0].t
        wall0 = time.monotonic()
        for k, frame in enumerate(frames):
            wait = wall0 + (frame.t - t_first) / speed - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            self.publish(frame, start_ns + int(round(frame.t * 1e9)))
            if between is not None:
                between(k, frame)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Roscore:
    """A ``roscore`` on a free port (a context manager): :attr:`uri` is its ROS_MASTER_URI and
    :attr:`env` the environment to start nodes with (``ROS_HOME`` in ``home``, logs included)."""

    def __init__(self, ros, home: str, timeout: float = 30.0):
        import os
        import subprocess

        self.ros = ros
        self.port = free_port()
        self.uri = f"http://127.0.0.1:{self.port}"
        self.env = {**os.environ, "ROS_MASTER_URI": self.uri, "ROS_HOME": str(home), "ROS_HOSTNAME": "127.0.0.1"}
        self.env.pop("ROS_IP", None)
        self.log = open(os.path.join(str(home), "roscore.log"), "w")
        self.proc = subprocess.Popen(["roscore", "-p", str(self.port)], env=self.env, stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        master = ros.rosgraph.Master("/scene_estimator_probe", master_uri=self.uri)
        deadline = time.monotonic() + timeout
        while True:
            try:
                master.getPid()
                break
            except Exception:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.close()
                    raise RuntimeError(f"roscore did not start on port {self.port} (see {self.log.name})")
                time.sleep(0.1)

    def close(self) -> None:
        import os
        import signal

        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)  # roscore and the rosout it started
            try:
                self.proc.wait(10)
            except Exception:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self.log.close()

    def __enter__(self) -> "Roscore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
