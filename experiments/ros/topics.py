"""The topics file of ``scene-estimator run --bag``: which topics of a ROS bag carry what.

YAML (JSON is valid YAML); every field is optional except ``sources[].topic`` and ``.type``::

    world_frame: world            # frame the scene is expressed in (default: world)
    window: 0.02                  # s, messages closer than this to a frame's first one join it
    reorder: 0.1                  # s, messages out of order by up to this much are sorted
    sources:
      - topic: /tf                # TF source: child frame id -> object id
        type: tf
        position_std: 0.01        # m, this source's position noise (inverse-variance fusion)
        objects: {cup_marker: cup, box_link: blue_box}
      - topic: /tracker/cup       # PoseStamped source: the whole topic is one object
        type: pose
        object: cup
        position_std: 0.02
    hands: {right_hand_link: human/right}   # TF frame id -> hand name

Mistakes raise :class:`~physics.errors.ObservationError` located by file, line and field.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

from physics.errors import ObservationError
from physics.fields import _Fields, read_yaml_with_lines

#: Source types and the ROS message type each one reads.
SOURCE_TYPES = {"tf": "tf2_msgs/msg/TFMessage", "pose": "geometry_msgs/msg/PoseStamped"}
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"


@dataclass(frozen=True)
class SourceSpec:
    """One perception source.

    ``type`` is ``"tf"`` (``tf2_msgs/TFMessage``: ``frames`` maps child frame ids to object ids) or
    ``"pose"`` (``geometry_msgs/PoseStamped``: the topic is the object ``object``).
    ``position_std`` (m) is the source's position noise, ``None`` for the estimator's configured one.
    """

    topic: str
    type: str
    frames: tuple[tuple[str, str], ...] = ()
    object: str | None = None
    position_std: float | None = None


@dataclass(frozen=True)
class TopicsSpec:
    """What to read from a bag. ``world_frame``: the scene's frame. ``window`` (s): a frame gathers
    the messages stamped less than this after its first one. ``reorder`` (s): how late (in stamp
    order) a message may arrive in the bag and still be sorted into place. ``hands``: TF frame id ->
    hand name. ``path``: the topics file, ``None`` for the convention used without one."""

    sources: tuple[SourceSpec, ...]
    world_frame: str = "world"
    window: float = 0.02
    reorder: float = 0.1
    hands: tuple[tuple[str, str], ...] = ()
    path: str | None = None
    lines: dict[str, int] = field(default_factory=dict, compare=False, repr=False)

    def locate(self, where: str) -> tuple[str | None, int | None]:
        """(file, line) of a field of the topics file, for error messages."""
        return self.path, self.lines.get(where)


def default_topics(object_ids: Iterable[str], world_frame: str = "world") -> TopicsSpec:
    """The convention without a topics file: ``/tf`` (and ``/tf_static``) are read, a child frame
    named like a scene object is that object, poses are chained to ``world_frame``."""
    ids = tuple(object_ids)
    return TopicsSpec(sources=(SourceSpec(TF_TOPIC, "tf", tuple((i, i) for i in ids)),), world_frame=world_frame)


def topics_from_dict(data: Any, object_ids: Iterable[str], *, path: str | None = None,
                     lines: dict[str, int] | None = None, world_frame: str | None = None) -> TopicsSpec:
    """Validate a decoded topics file against the scene's ``object_ids``. ``world_frame`` (from the
    command line) wins over the file's. Raises :class:`ObservationError`."""
    f = _Fields(path, lines or {}, ObservationError)
    ids = set(object_ids)
    data = f.mapping(data if data is not None else {}, "")
    f.only(data, {"world_frame", "window", "reorder", "sources", "hands"}, "")

    def text(value: Any, where: str) -> str:
        if not isinstance(value, str) or not value:
            raise f.error(where, f"must be a non-empty string, got {value!r}")
        return value

    def object_id(value: Any, where: str) -> str:
        oid = text(value, where)
        if oid not in ids:
            raise f.error(where, f"unknown object id {oid!r} (the scene has: {', '.join(sorted(ids))})")
        return oid

    raw_sources = data.get("sources")
    if not isinstance(raw_sources, list) or not raw_sources:
        raise f.error("sources", "must be a non-empty list of sources (topic, type, ...)")
    sources = []
    for i, raw in enumerate(raw_sources):
        where = f"sources[{i}]"
        raw = f.mapping(raw, where)
        f.only(raw, {"topic", "type", "objects", "object", "position_std"}, where)
        for key in ("topic", "type"):
            if key not in raw:
                raise f.error(f"{where}.{key}", "missing")
        topic = text(raw["topic"], f"{where}.topic")
        kind = raw["type"]
        if kind not in SOURCE_TYPES:
            raise f.error(f"{where}.type", f"must be one of {', '.join(SOURCE_TYPES)}, got {kind!r}")
        std = raw.get("position_std")
        if std is not None:
            std = f.number(std, f"{where}.position_std", positive=True)
        if kind == "tf":
            if "object" in raw:
                raise f.error(f"{where}.object", "a tf source maps frames with 'objects: {frame: object}'")
            frames = f.mapping(raw.get("objects", {}), f"{where}.objects")
            pairs = tuple((text(k, f"{where}.objects"), object_id(v, f"{where}.objects.{k}"))
                          for k, v in frames.items())
            sources.append(SourceSpec(topic, kind, frames=pairs, position_std=std))
        else:
            if "objects" in raw:
                raise f.error(f"{where}.objects", "a pose source is one object: 'object: <id>'")
            if "object" not in raw:
                raise f.error(f"{where}.object", "missing")
            sources.append(SourceSpec(topic, kind, object=object_id(raw["object"], f"{where}.object"),
                                      position_std=std))
    hands = f.mapping(data.get("hands", {}) or {}, "hands")
    hand_pairs = tuple((text(k, "hands"), text(v, f"hands.{k}")) for k, v in hands.items())
    world = world_frame or text(data.get("world_frame", "world"), "world_frame")
    window = f.number(data.get("window", 0.02), "window", nonneg=True)
    reorder = f.number(data.get("reorder", 0.1), "reorder", nonneg=True)
    return TopicsSpec(tuple(sources), world, window, reorder, hand_pairs, path, dict(lines or {}))


def load_topics(path: str, object_ids: Iterable[str], world_frame: str | None = None) -> TopicsSpec:
    """Read and validate a topics file (YAML or JSON). Raises :class:`ObservationError`."""
    data, lines = read_yaml_with_lines(path, "topics file", ObservationError)
    return topics_from_dict(data, object_ids, path=str(path), lines=lines, world_frame=world_frame)
