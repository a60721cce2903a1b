"""Bad input of the live ROS node (:mod:`experiments.ros.node`, whose module docstring describes each
kind): the kinds (:data:`BAD_KINDS`), their counts by kind and by topic with throttled log lines
(:class:`BadInput`), the check that drops a message's non-finite transforms or pose
(:func:`finite_part`), and the ROS 1 message type each source type of the topics file must carry
(:data:`ROS1_TYPES`).
"""
from __future__ import annotations

import math
import threading

#: ROS 1 message type of each source type of the topics file
ROS1_TYPES = {"tf": "tf2_msgs/TFMessage", "pose": "geometry_msgs/PoseStamped"}
BAD_KINDS = ("non_finite", "unknown_frame", "late", "time_backwards", "wrong_type", "malformed")


class BadInput:
    """Counts of bad input by kind and by topic, the last report, and the log lines (throttled)."""

    def __init__(self, log, first: int, every: int):
        self.log = log
        self.first, self.every = first, every
        self.counts = {k: 0 for k in BAD_KINDS}
        self.by_topic: dict[str, dict[str, int]] = {}
        self.last: str | None = None
        self.version = 0
        self._lock = threading.Lock()

    def __call__(self, kind: str, topic: str, field: str, message: str) -> None:
        with self._lock:
            self.counts[kind] += 1
            per = self.by_topic.setdefault(topic, {})
            per[kind] = n = per.get(kind, 0) + 1
            text = f"bad input ({kind}) on {topic}" + (f", field {field}" if field else "") + f": {message}"
            self.last = text
            self.version += 1
        if n <= self.first or n % self.every == 0:
            self.log(text + (f" [{n} so far on this topic]" if n > self.first else ""))

    def to_json(self) -> dict:
        with self._lock:
            return {"total": sum(self.counts.values()), "counts": dict(self.counts),
                    "by_topic": {t: dict(c) for t, c in self.by_topic.items()}, "last": self.last}


def _finite(values) -> bool:
    return all(math.isfinite(v) for v in values)


def finite_part(msg, kind: str, topic: str, bad: BadInput):
    """``msg`` without its non-finite transforms (TF) or None (a non-finite pose), reported to ``bad``."""
    if kind == "pose":
        p = msg.pose
        for part, v in (("pose.position", (p.position.x, p.position.y, p.position.z)),
                        ("pose.orientation", (p.orientation.x, p.orientation.y, p.orientation.z,
                                              p.orientation.w))):
            if not _finite(v):
                bad("non_finite", topic, part, f"non-finite value {list(v)} in frame "
                                               f"{msg.header.frame_id!r}; message dropped")
                return None
        return msg
    keep = []
    for i, t in enumerate(msg.transforms):
        tr, rot = t.transform.translation, t.transform.rotation
        for part, v in (("translation", (tr.x, tr.y, tr.z)), ("rotation", (rot.x, rot.y, rot.z, rot.w))):
            if not _finite(v):
                bad("non_finite", topic, f"transforms[{i}].transform.{part}",
                    f"non-finite value {list(v)} in {t.header.frame_id!r} -> {t.child_frame_id!r}; "
                    f"transform dropped")
                break
        else:
            keep.append(t)
    if len(keep) < len(msg.transforms):
        msg.transforms = keep
    return msg if keep else None
