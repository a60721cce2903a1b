"""Messages to frames, whatever the messages come from (a bag: :mod:`experiments.ros.reader`; live:
:mod:`experiments.ros.node`): ``tf2_msgs/TFMessage`` and ``geometry_msgs/PoseStamped`` messages are
decoded (:func:`decode_message`), sorted by stamp within the ``reorder`` window, applied to a TF
tree (:class:`TfTree`: the latest transform of each parent -> child edge) so that every pose is
chained to the world frame at its message's time, grouped into frames by timestamp windows of
``window`` s, and the detections of an object by several sources fused by inverse variance
(:func:`fuse`); :class:`FrameAssembler` does the sorting, chaining and grouping.

Units: metres, seconds (stamps in integer nanoseconds); poses ``(7,)`` as position x, y, z and
quaternion x, y, z, w.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from estimator.observations import Detection, Frame
from experiments.ros.topics import TopicsSpec
from physics.transforms import pose_compose, pose_inverse


def fuse(detections: list[Detection]) -> Detection:
    """Inverse-variance fusion of detections of one object: position = sum(p_i / s_i^2) / sum(1 / s_i^2),
    std = (sum 1 / s_i^2)^-1/2 (metres); the orientation is that of the most precise detection
    that has one. Detections without a ``position_std`` count with equal weights (std ``None``)."""
    if len(detections) == 1:
        return detections[0]
    if any(d.position_std is None for d in detections):
        w = np.ones(len(detections))
        std = None
    else:
        w = np.array([1.0 / d.position_std ** 2 for d in detections])
        std = float(1.0 / math.sqrt(w.sum()))
    pos = (w[:, None] * np.array([d.position for d in detections])).sum(axis=0) / w.sum()
    oriented = [(i, d) for i, d in enumerate(detections) if d.orientation is not None]
    orn = max(oriented, key=lambda p: w[p[0]])[1].orientation if oriented else None
    return Detection(pos, orn, std)


class TfTree:
    """The latest transform of each parent -> child edge (child frame id -> (parent, pose (7,)))."""

    def __init__(self):
        self.edges: dict[str, tuple[str, np.ndarray]] = {}

    def set(self, parent: str, child: str, pose: np.ndarray) -> None:
        self.edges[child] = (parent, pose)

    def _to_root(self, frame: str) -> tuple[str, np.ndarray | None]:
        """(root frame, pose of ``frame`` in it; ``None`` when ``frame`` is the root)."""
        pose = None
        seen = {frame}
        while frame in self.edges:
            parent, edge = self.edges[frame]
            pose = edge if pose is None else pose_compose(edge, pose)
            frame = parent
            if frame in seen:
                break  # a loop: report as unconnected
            seen.add(frame)
        return frame, pose

    def lookup(self, world: str, frame: str) -> np.ndarray | None:
        """Pose (7,) of ``frame`` in ``world``, or ``None`` when no chain of transforms joins them."""
        root, pose = self._to_root(frame)
        world_root, world_pose = self._to_root(world)
        if root != world_root:
            return None
        if pose is None:
            pose = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        return pose if world_pose is None else pose_compose(pose_inverse(world_pose), pose)

    def root(self, frame: str) -> str:
        return self._to_root(frame)[0]


def _stamp_ns(stamp) -> int:
    """A header stamp in ns: rosbags' ``builtin_interfaces/Time`` (``sec``, ``nanosec``) or rospy's
    ``Time`` (``secs``, ``nsecs``)."""
    if hasattr(stamp, "nanosec"):
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return int(stamp.secs) * 1_000_000_000 + int(stamp.nsecs)


def _pose7(translation, rotation) -> np.ndarray:
    return np.array([translation.x, translation.y, translation.z, rotation.x, rotation.y, rotation.z, rotation.w],
                    dtype=float)


@dataclass(frozen=True)
class _Item:
    """One message, decoded: ``kind`` "tf" (``transforms``: (parent, child, pose)) or "pose"."""

    stamp_ns: int
    seq: int
    kind: str
    source: int
    topic: str
    transforms: tuple = ()
    frame_id: str = ""
    pose: np.ndarray | None = None


def decode_message(msg, tf: bool, topic: str, source: int, seq: int) -> _Item:
    """A ``tf2_msgs/TFMessage`` (``tf``) or ``geometry_msgs/PoseStamped`` as an :class:`_Item`, from a
    bag (rosbags' messages) or live (rospy's: the same fields). ``source``: index of the topic's
    source in the topics file (-1: TF only); ``seq``: arrival order. A TF message's stamp is the
    latest of its transforms'."""
    if tf:
        tfs = tuple((t.header.frame_id, t.child_frame_id, _pose7(t.transform.translation, t.transform.rotation))
                    for t in msg.transforms)
        stamp = max((_stamp_ns(t.header.stamp) for t in msg.transforms), default=0)
        return _Item(stamp, seq, "tf", source, topic, transforms=tfs)
    p = msg.pose
    return _Item(_stamp_ns(msg.header.stamp), seq, "pose", source, topic, frame_id=msg.header.frame_id,
                 pose=_pose7(p.position, p.orientation))


class FrameAssembler:
    """Decoded messages (:class:`_Item`) in, :class:`Frame` s out: the part of the bag reader's module
    docstring (:mod:`experiments.ros.reader`) that does not depend on where the messages come from
    (the reorder window, TF chains at each message's time, timestamp windows, fusion). Shared by
    :class:`~experiments.ros.reader.BagFrameReader` and the live ROS node (:mod:`experiments.ros.node`).

    ``t0_ns``: stamp of ``t = 0``. ``report(kind, topic, message)`` is called for each message or
    pose that is not used: kind ``"late"`` (stamped more than ``reorder`` before the newest message,
    or at or before the last frame closed: frame times strictly increase), ``"unknown_frame"``
    (no transform chain to the world frame), ``"non_finite"`` (a NaN or a zero quaternion after
    chaining); it may raise to stop.

    :meth:`push` takes messages in arrival order; a message is *released* (applied to the TF tree
    and grouped) once the newest stamp has passed it by ``reorder``, or (live) once :meth:`advance`
    is told that the time has (a message released that way is not late yet: it is used unless its
    frame was closed); :meth:`finish` releases everything at the end of a stream.
    """

    def __init__(self, topics: TopicsSpec, t0_ns: int, report: Callable[[str, str, str], None]):
        self.topics = topics
        self.t0_ns = int(t0_ns)
        self.report = report
        self.tf = TfTree()
        self.late = 0
        self.reorder_ns = int(round(topics.reorder * 1e9))
        self.window_ns = int(round(topics.window * 1e9))
        self.newest = -math.inf
        self.released = -math.inf  # every message stamped before this has been released
        self.closed = -math.inf  # stamp of the last frame closed
        self._heap: list = []
        self._frames = [dict(s.frames) for s in topics.sources]
        self._hands = dict(topics.hands)
        self._start = self._last = None
        self._objects: dict[tuple[int, str], np.ndarray] = {}
        self._hand_pos: dict[str, np.ndarray] = {}

    def t(self, stamp_ns: int) -> float:
        return (stamp_ns - self.t0_ns) / 1e9

    def push(self, item: _Item) -> Iterator[Frame]:
        """Take one message; yields the frames it completes (in bag order: stamp order within the
        reorder window)."""
        if item.kind == "tf" and not item.transforms:
            return  # an empty TF message has no time and places nothing
        if item.stamp_ns < self.newest - self.reorder_ns or item.stamp_ns <= self.closed:
            self.late += 1
            why = (f"more than {self.topics.reorder} s late" if item.stamp_ns < self.newest - self.reorder_ns
                   else f"after the frame at {self.t(self.closed):.3f} s was closed")
            self.report("late", item.topic, f"message stamped {self.t(item.stamp_ns):.3f} s arrived {why}; dropped")
            return
        self.newest = max(self.newest, item.stamp_ns)
        heapq.heappush(self._heap, (item.stamp_ns, 0 if item.kind == "tf" else 1, item.seq, item))
        yield from self._release(self.newest - self.reorder_ns)

    def advance(self, now_ns: int) -> Iterator[Frame]:
        """Live: the time is ``now_ns`` (in stamp time): release the messages stamped more than
        ``reorder`` before it, and close the pending frame once no message may join it any more."""
        yield from self._release(now_ns - self.reorder_ns)
        if (self._start is not None and self.released > self._last
                and self.released >= self._start + self.window_ns):
            yield self._close()

    def finish(self) -> Iterator[Frame]:
        """The end of the stream: release everything, close the last frame."""
        yield from self._release(math.inf)
        if self._start is not None:
            yield self._close()

    def _release(self, threshold) -> Iterator[Frame]:
        self.released = max(self.released, threshold)
        while self._heap and self._heap[0][0] < threshold:
            item = heapq.heappop(self._heap)[3]
            for stamp, obs in self._observations(item):
                yield from self._group(stamp, obs)

    def _group(self, stamp: int, obs: tuple) -> Iterator[Frame]:
        if (self._start is not None and stamp - self._start >= self.window_ns and stamp > self._last):
            yield self._close()
        if self._start is None:
            self._start = stamp
        self._last = stamp
        if obs[0] == "object":
            self._objects[(obs[1], obs[2])] = obs[3]
        else:
            self._hand_pos[obs[1]] = obs[2]

    def _close(self) -> Frame:
        frame = self._frame(self._last, self._objects, self._hand_pos)
        self.closed = self._last
        self._start, self._objects, self._hand_pos = None, {}, {}
        return frame

    def _place(self, frame_id: str, pose: np.ndarray | None, t: float, topic: str, what: str) -> np.ndarray | None:
        """World pose of ``pose`` given in ``frame_id`` (``None``: the frame itself), or ``None``
        after reporting a missing transform or a zero quaternion."""
        world = self.topics.world_frame
        chain = self.tf.lookup(world, frame_id)
        if chain is None:
            self.report("unknown_frame", topic,
                        f"t={t:.3f} s: no transform from {world!r} to {frame_id!r} to place {what} (the TF tree "
                        f"joins {frame_id!r} to {self.tf.root(frame_id)!r}, {world!r} to {self.tf.root(world)!r})")
            return None
        out = chain if pose is None else pose_compose(chain, pose)
        q = out[3:]
        n = float(np.linalg.norm(q))
        if not np.all(np.isfinite(out)) or n < 1e-9:
            self.report("non_finite", topic,
                        f"t={t:.3f} s: non-finite pose or zero-length quaternion for {what} in {frame_id!r}")
            return None
        q = q / n
        return np.concatenate([out[:3], -q if q[3] < 0 else q])

    def _observations(self, item: _Item) -> Iterator[tuple[int, tuple]]:
        """(stamp ns, ("object", source, id, pose) | ("hand", name, position)) of one released message."""
        t = self.t(item.stamp_ns)
        hands = self._hands
        if item.kind == "tf":
            for parent, child, pose in item.transforms:
                self.tf.set(parent, child, pose)
            for parent, child, _ in item.transforms:
                oid = self._frames[item.source].get(child) if item.source >= 0 else None
                if oid is not None or child in hands:
                    placed = self._place(child, None, t, item.topic, f"frame {child!r}")
                    if placed is None:
                        continue
                    if oid is not None:
                        yield item.stamp_ns, ("object", item.source, oid, placed)
                    if child in hands:
                        yield item.stamp_ns, ("hand", hands[child], placed[:3])
        else:
            oid = self.topics.sources[item.source].object
            placed = self._place(item.frame_id, item.pose, t, item.topic, f"object {oid!r}")
            if placed is not None:
                yield item.stamp_ns, ("object", item.source, oid, placed)

    def _frame(self, stamp_ns: int, objects: dict, hands: dict) -> Frame:
        by_object: dict[str, list[Detection]] = {}
        for (source, oid), pose in objects.items():
            det = Detection(pose[:3], pose[3:], self.topics.sources[source].position_std)
            by_object.setdefault(oid, []).append(det)
        return Frame(self.t(stamp_ns), {oid: fuse(d) for oid, d in sorted(by_object.items())}, dict(hands))
