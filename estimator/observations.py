"""Perception input: frames of perceived object poses, read from a JSON Lines stream.

One frame per line::

    {"t": 0.0333, "objects": {"cup": {"position": [0.1, 0.2, 0.68], "orientation": [0, 0, 0, 1]}},
     "hands": {"human/right": [0.3, -0.1, 0.9]}}

``t`` is in seconds and strictly increasing; positions in metres; quaternions (x, y, z, w), normalised
on reading (a zero-length one is an error). ``orientation`` may be omitted (orientation not measured).
An object missing from a frame is not perceived in it. ``hands`` is optional. ``position_std``
(metres, per object) overrides the configured perception noise for that detection. ``cameras``
(optional) lists the cameras that took the frame, ``[{"id": "head", "position": [..], "target": [..]
| "orientation": [x, y, z, w], "fov_deg": 60, "aspect", "near", "far", "up"}]``, validated like the
scene's ``camera`` (:func:`physics.scene.parse_camera`); it overrides the scene's camera for that
frame (negative evidence then asks these cameras; an empty list: no camera, no negative evidence).

Every malformed frame raises :class:`~physics.errors.ObservationError` naming file, line and field;
with ``skip_bad_frames=True`` it is dropped instead, counted in :attr:`ObservationReader.skipped` and
reported through the ``warn`` callback.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator, TextIO

import numpy as np

from physics.errors import ObservationError
from physics.fields import _Fields
from physics.scene import CameraSpec, camera_to_dict, parse_camera


@dataclass(frozen=True)
class Detection:
    """One perceived object in one frame: ``position (3,)`` metres, ``orientation (4,)`` x,y,z,w
    unit quaternion or ``None`` when not measured, optional per-detection ``position_std`` (m)."""

    position: np.ndarray
    orientation: np.ndarray | None = None
    position_std: float | None = None


@dataclass(frozen=True)
class Frame:
    """A perception frame at time ``t`` (s): detections by object id, tracked hands ``(3,)`` and
    the cameras that took it by id (``None``: the scene's camera)."""

    t: float
    objects: dict[str, Detection] = field(default_factory=dict)
    hands: dict[str, np.ndarray] = field(default_factory=dict)
    line: int | None = None
    cameras: dict[str, CameraSpec] | None = None

    def to_json(self) -> dict:
        objs = {}
        for oid, d in self.objects.items():
            o = {"position": [float(v) for v in d.position]}
            if d.orientation is not None:
                o["orientation"] = [float(v) for v in d.orientation]
            if d.position_std is not None:
                o["position_std"] = d.position_std
            objs[oid] = o
        out = {"t": self.t, "objects": objs}
        if self.hands:
            out["hands"] = {k: [float(x) for x in v] for k, v in self.hands.items()}
        if self.cameras is not None:
            out["cameras"] = [{"id": cid, **camera_to_dict(c)} for cid, c in self.cameras.items()]
        return out


def _finite_vector(value, n: int, err: Callable[[str, str], ObservationError], where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise err(where, f"must be a list of {n} numbers, got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise err(f"{where}[{i}]", f"must be a number, got {v!r}")
        if not math.isfinite(v):
            raise err(f"{where}[{i}]", f"must be finite, got {v!r}")
        out.append(float(v))
    return np.array(out)


def parse_frame(data, *, known_ids: Iterable[str] | None = None, path: str | None = None,
                line: int | None = None) -> Frame:
    """Validate one decoded frame (a dict). Raises :class:`ObservationError`."""

    def err(where: str, message: str) -> ObservationError:
        return ObservationError(message, path=path, line=line, field=where)

    if not isinstance(data, dict):
        raise err("", f"a frame must be a JSON object, got {type(data).__name__}")
    for key in data:
        if key not in ("t", "objects", "hands", "cameras"):
            raise err(key, "unknown field (expected t, objects, hands, cameras)")
    if "t" not in data:
        raise err("t", "missing")
    t = data["t"]
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
        raise err("t", f"must be a finite number of seconds, got {t!r}")
    raw_objects = data.get("objects", {})
    if not isinstance(raw_objects, dict):
        raise err("objects", "must be a JSON object keyed by object id")
    known = set(known_ids) if known_ids is not None else None
    objects: dict[str, Detection] = {}
    for oid, raw in raw_objects.items():
        where = f"objects.{oid}"
        if known is not None and oid not in known:
            raise err(where, f"unknown object id {oid!r} (the scene has: {', '.join(sorted(known))})")
        if not isinstance(raw, dict):
            raise err(where, "must be a JSON object with position and orientation")
        for key in raw:
            if key not in ("position", "orientation", "position_std"):
                raise err(f"{where}.{key}", "unknown field (expected position, orientation, position_std)")
        if "position" not in raw:
            raise err(f"{where}.position", "missing")
        pos = _finite_vector(raw["position"], 3, err, f"{where}.position")
        orn = None
        if raw.get("orientation") is not None:
            q = _finite_vector(raw["orientation"], 4, err, f"{where}.orientation")
            n = float(np.linalg.norm(q))
            if n < 1e-9:
                raise err(f"{where}.orientation", "zero-length quaternion (expected x, y, z, w)")
            q = q / n
            orn = -q if q[3] < 0 else q
        std = raw.get("position_std")
        if std is not None:
            if isinstance(std, bool) or not isinstance(std, (int, float)) or not math.isfinite(std) or std <= 0:
                raise err(f"{where}.position_std", f"must be a positive number of metres, got {std!r}")
            std = float(std)
        objects[oid] = Detection(pos, orn, std)
    hands: dict[str, np.ndarray] = {}
    raw_hands = data.get("hands", {}) or {}
    if not isinstance(raw_hands, dict):
        raise err("hands", "must be a JSON object keyed by hand name")
    for name, value in raw_hands.items():
        hands[str(name)] = _finite_vector(value, 3, err, f"hands.{name}")
    cameras = None
    if data.get("cameras") is not None:
        cameras = _parse_cameras(data["cameras"], path, line)
    return Frame(float(t), objects, hands, line, cameras)


def _parse_cameras(raw, path: str | None, line: int | None) -> dict[str, CameraSpec]:
    """The ``cameras`` list of a frame, by id (ids unique; a missing id is the camera's index)."""
    f = _Fields(path, {"": line} if line is not None else {}, ObservationError)
    if not isinstance(raw, list):
        raise f.error("cameras", f"must be a list of cameras, got {type(raw).__name__}")
    out: dict[str, CameraSpec] = {}
    for i, c in enumerate(raw):
        where = f"cameras[{i}]"
        spec = parse_camera(f, c, where, extra={"id"}, orientation=True)
        cid = c.get("id", str(i))
        if not isinstance(cid, str) or not cid:
            raise f.error(f"{where}.id", f"must be a non-empty string, got {cid!r}")
        if cid in out:
            raise f.error(f"{where}.id", f"duplicate camera id {cid!r}")
        out[cid] = spec
    return out


class ObservationReader:
    """Iterate over the frames of a JSONL observation file, validating each.

    Args:
        path: the ``.jsonl`` file.
        known_ids: object ids of the scene; any other id is an error.
        skip_bad_frames: drop malformed frames instead of raising; they are counted in
            :attr:`skipped` and described through ``warn``.
        warn: called with a message for each dropped frame (default: no-op).
        stream: an open text stream to read instead of opening ``path`` (standard input, a socket's
            file); ``path`` then only names it in messages (``<stdin>:5: t: ...``). Lines are read
            as they come (nothing is read ahead of the frame being yielded but what the stream has
            already delivered); the stream is closed at the end.
    """

    def __init__(self, path: str, known_ids: Iterable[str] | None = None, *, skip_bad_frames: bool = False,
                 warn: Callable[[str], None] | None = None, stream: TextIO | None = None):
        self.path = str(path)
        self.stream = stream
        self.known_ids = tuple(known_ids) if known_ids is not None else None
        self.skip_bad_frames = skip_bad_frames
        self.warn = warn or (lambda msg: None)
        self.skipped = 0
        self.frames_read = 0

    def __iter__(self) -> Iterator[Frame]:
        try:
            fh = self.stream if self.stream is not None else open(self.path, encoding="utf-8")
        except FileNotFoundError:
            raise ObservationError("observation file not found", path=self.path) from None
        last_t = -math.inf
        with fh:
            for lineno, text in enumerate(fh, start=1):
                if not text.strip():
                    continue
                try:
                    try:
                        data = json.loads(text, parse_constant=_reject_constant)
                    except json.JSONDecodeError as exc:
                        raise ObservationError(f"invalid JSON: {exc.msg} (column {exc.colno})",
                                               path=self.path, line=lineno) from None
                    except _NonFinite as exc:
                        raise ObservationError(f"non-finite number {exc.args[0]} is not allowed",
                                               path=self.path, line=lineno, field=_guess_field(text)) from None
                    frame = parse_frame(data, known_ids=self.known_ids, path=self.path, line=lineno)
                    if frame.t <= last_t:
                        raise ObservationError(f"time must be strictly increasing: {frame.t} after {last_t}",
                                               path=self.path, line=lineno, field="t")
                except ObservationError as exc:
                    if not self.skip_bad_frames:
                        raise
                    self.skipped += 1
                    self.warn(f"skipped bad frame: {exc}")
                    continue
                last_t = frame.t
                self.frames_read += 1
                yield frame


class _NonFinite(ValueError):
    pass


def _reject_constant(name: str):
    raise _NonFinite(name)


def _guess_field(text: str) -> str | None:
    """Best-effort field path of the first NaN/Infinity token in a raw JSON line."""
    for token in ("NaN", "-Infinity", "Infinity"):
        pos = text.find(token)
        if pos < 0:
            continue
        try:
            data = json.loads(text.replace(token, '"__BAD__"', 1), parse_constant=lambda c: 0.0)
        except json.JSONDecodeError:
            return None
        return _find_marker(data, "")
    return None


def _find_marker(value, where: str) -> str | None:
    if value == "__BAD__":
        return where
    if isinstance(value, dict):
        for k, v in value.items():
            found = _find_marker(v, f"{where}.{k}" if where else str(k))
            if found:
                return found
    if isinstance(value, list):
        for i, v in enumerate(value):
            found = _find_marker(v, f"{where}[{i}]")
            if found:
                return found
    return None


def read_observations(path: str, known_ids: Iterable[str] | None = None) -> list[Frame]:
    """All frames of ``path`` as a list (raises on the first bad frame)."""
    return list(ObservationReader(path, known_ids))


def write_observations(path: str, frames: Iterable[Frame]) -> None:
    """Write frames as JSON Lines."""
    with open(path, "w", encoding="utf-8") as fh:
        for f in frames:
            fh.write(json.dumps(f.to_json()) + "\n")
