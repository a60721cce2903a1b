"""Perception from ROS bags: an input adapter that turns the messages of a ROS 1 or ROS 2 bag into
the estimator's :class:`~estimator.observations.Frame` stream.

Read with the pure-Python ``rosbags`` library (``AnyReader`` reads both formats). Sources (see
:mod:`experiments.ros.topics`): ``tf2_msgs/TFMessage`` topics, whose transforms of mapped child
frames are object poses, and ``geometry_msgs/PoseStamped`` topics, one object each. Every pose is
chained to the world frame through the TF tree *at the message's time*: the transforms of ``/tf`` and
``/tf_static`` (and of every tf source) are applied in stamp order, the latest transform of each
parent -> child edge is kept, and static transforms hold for the whole bag (they are read first).
Static transforms place frames; they are not detections.

**Time.** A message's time is its header stamp (a TF message's: the latest stamp of its
transforms); ``t`` of a frame is seconds since the bag's start (:attr:`BagFrameReader.t0_ns`, its
first recorded message). Empty TF messages are ignored, so a bag has no frame where nothing was seen. Messages are sorted by stamp within the
``reorder`` window (0.1 s): a message stamped more than ``reorder`` before the newest stamp read so
far is too late, dropped and counted (:attr:`BagFrameReader.late`).

**Frames.** Timestamp windows: a frame starts at the first message after the previous frame and
gathers every message stamped less than ``window`` (0.02 s) after it (with ``window: 0``, one frame
per distinct stamp); its ``t`` is its latest stamp, so frame times strictly increase.
Within a frame, the latest detection of each (source, object) is kept and an object seen by several
sources is fused by inverse variance (:func:`fuse`). An object is unperceived only if no source saw
it. Hands are the latest positions of their TF frames in the frame.

Units: metres, seconds; quaternions x, y, z, w.
"""
from __future__ import annotations

import heapq
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from estimator.observations import Detection, Frame
from experiments.ros.topics import SOURCE_TYPES, TF_STATIC_TOPIC, TF_TOPIC, SourceSpec, TopicsSpec
from physics.errors import ObservationError
from physics.transforms import pose_compose, pose_inverse

TF_TYPE = SOURCE_TYPES["tf"]
POSE_TYPE = SOURCE_TYPES["pose"]


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
    """Decoded messages (:class:`_Item`) in, :class:`Frame` s out: the part of the module docstring
    that does not depend on where the messages come from (the reorder window, TF chains at each
    message's time, timestamp windows, fusion). Shared by :class:`BagFrameReader` and the live ROS
    node (:mod:`experiments.ros.node`).

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


def open_reader(path: str):
    """An opened ``AnyReader`` on ``path`` (a ROS 1 ``.bag`` file or a ROS 2 bag folder), or an
    :class:`ObservationError` naming the file."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not os.path.exists(path):
        raise ObservationError("bag not found", path=path)
    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises several types for a file that is not a bag
        raise ObservationError(f"not a readable ROS 1 or ROS 2 bag: {exc}", path=path) from None
    return reader


class BagFrameReader:
    """Iterate over the frames of a ROS bag (see the module docstring for time and grouping).

    Args:
        path: a ROS 1 ``.bag`` file or a ROS 2 bag folder.
        topics: the sources (:func:`~experiments.ros.topics.load_topics` or ``default_topics``).
        skip_bad_frames: a pose that cannot be placed (no transform chain to the world frame, a
            zero quaternion) is dropped with a counted warning instead of raising.
        warn: called with a message for each dropped pose or late message.
    """

    def __init__(self, path: str, topics: TopicsSpec, *, skip_bad_frames: bool = False,
                 warn: Callable[[str], None] | None = None):
        self.path = str(path)
        self.topics = topics
        self.skip_bad_frames = skip_bad_frames
        self.warn = warn or (lambda msg: None)
        self.skipped = 0
        self.late = 0
        self.frames_read = 0
        self.tf = TfTree()
        reader = open_reader(self.path)  # fail early: a missing bag or topic, before any estimation
        try:
            self._connections(reader)
            self.t0_ns = int(reader.start_time) if reader.message_count else 0
        finally:
            reader.close()

    # -- errors ---------------------------------------------------------------------------------------

    def _topic_error(self, source: SourceSpec | None, index: int | None, message: str) -> ObservationError:
        if self.topics.path is not None and index is not None:
            where = f"sources[{index}].topic"
            path, line = self.topics.locate(where)
            return ObservationError(message, path=path, line=line, field=where)
        return ObservationError(message, path=self.path, field=source.topic if source else None)

    def _bad(self, message: str, topic: str) -> None:
        if not self.skip_bad_frames:
            raise ObservationError(message, path=self.path, field=topic)
        self.skipped += 1
        self.warn(f"skipped: {self.path}: {topic}: {message}")

    # -- reading --------------------------------------------------------------------------------------

    def _connections(self, reader) -> tuple[list, dict[int, int]]:
        """Connections to read and, for each connection id, its source index (-1: TF only)."""
        by_topic: dict[str, list] = {}
        for c in reader.connections:
            by_topic.setdefault(c.topic, []).append(c)
        chosen: dict[int, int] = {}
        conns = []
        for i, src in enumerate(self.topics.sources):
            if src.topic not in by_topic:
                raise self._topic_error(src, i if self.topics.path else None,
                                        f"topic {src.topic} is not in {self.path} (it has: "
                                        f"{', '.join(sorted(by_topic)) or 'no topics'})")
            for c in by_topic[src.topic]:
                if c.msgtype != SOURCE_TYPES[src.type]:
                    raise self._topic_error(src, i if self.topics.path else None,
                                            f"topic {src.topic} carries {c.msgtype}, not {SOURCE_TYPES[src.type]} "
                                            f"(type {src.type})")
                if c.id not in chosen:
                    chosen[c.id] = i
                    conns.append(c)
        for c in by_topic.get(TF_TOPIC, []):
            if c.id not in chosen and c.msgtype == TF_TYPE:
                chosen[c.id] = -1
                conns.append(c)
        return conns, chosen

    def _messages(self, reader, connections: list) -> Iterator[tuple]:
        """(connection, decoded message) of ``connections`` in recorded order; a bag that cannot be
        read or decoded raises :class:`ObservationError` naming it, not rosbags' own error."""
        stream = reader.messages(connections=connections)
        while True:
            try:
                conn, _, raw = next(stream)
                msg = reader.deserialize(raw, conn.msgtype)
            except StopIteration:
                return
            except Exception as exc:  # rosbags' read and decode errors have several types
                raise ObservationError(f"cannot read the bag: {type(exc).__name__}: {exc}", path=self.path) from None
            yield conn, msg

    def _report(self, kind: str, topic: str, message: str) -> None:
        if kind == "late":
            self.late += 1
            self.warn(f"{self.path}: {topic}: {message}")
        else:
            self._bad(message, topic)

    def __iter__(self) -> Iterator[Frame]:
        reader = open_reader(self.path)
        try:
            self.late = self.skipped = self.frames_read = 0
            asm = FrameAssembler(self.topics, self.t0_ns, self._report)
            self.tf = asm.tf
            conns, sources = self._connections(reader)
            statics = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC and c.msgtype == TF_TYPE]
            for conn, msg in self._messages(reader, statics) if statics else ():  # []: rosbags reads all
                for parent, child, pose in decode_message(msg, True, conn.topic, -1, 0).transforms:
                    asm.tf.set(parent, child, pose)
            for seq, (conn, msg) in enumerate(self._messages(reader, conns)):
                item = decode_message(msg, conn.msgtype == TF_TYPE, conn.topic, sources[conn.id], seq)
                for frame in asm.push(item):
                    self.frames_read += 1
                    yield frame
            for frame in asm.finish():
                self.frames_read += 1
                yield frame
        finally:
            reader.close()


def read_bag_frames(path: str, topics: TopicsSpec, *, skip_bad_frames: bool = False) -> list[Frame]:
    """All frames of a bag as a list."""
    return list(BagFrameReader(path, topics, skip_bad_frames=skip_bad_frames))
