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
sources is fused by inverse variance (:func:`~experiments.ros.assembler.fuse`). An object is
unperceived only if no source saw it. Hands are the latest positions of their TF frames in the frame.
The sorting, chaining and grouping, shared with the live node, are in :mod:`experiments.ros.assembler`.

Units: metres, seconds; quaternions x, y, z, w.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterator

from estimator.observations import Frame
from experiments.ros.assembler import FrameAssembler, TfTree, decode_message
from experiments.ros.topics import SOURCE_TYPES, TF_STATIC_TOPIC, TF_TOPIC, SourceSpec, TopicsSpec
from physics.errors import ObservationError

TF_TYPE = SOURCE_TYPES["tf"]
POSE_TYPE = SOURCE_TYPES["pose"]


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
