"""Validation of a scenario file's parsed mapping into a :class:`~experiments.scenarios.specs.Scenario`
(:func:`scenario_from_dict`; the format: :mod:`experiments.scenarios`). Every problem is a
:class:`~physics.errors.SceneError` naming the file, the line and the field."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from experiments.scenarios.specs import (
    HandSpec,
    HandTarget,
    ObjectRandomization,
    Randomization,
    Scenario,
    TorsoSpec,
    Waypoint,
)
from experiments.simulation.perception import PerceptionConfig
from physics.errors import SceneError
from physics.fields import _Fields
from physics.scene import Scene, scene_from_dict

_TOP = {"name", "description", "duration", "settle", "scene", "hand", "torso", "perception", "randomize"}
_WAYPOINT = {"t", "to", "by", "rpy", "grasp", "release", "collide"}
_HAND = {"radius", "mass", "max_force", "start", "rpy", "holding", "collide", "script"}
_OBJ_RANDOM = ("position", "yaw", "size", "mass", "friction", "rolling_friction", "spinning_friction",
               "restitution")


def _range(f: _Fields, value: Any, where: str, *, positive: bool = False) -> tuple[float, float]:
    lo, hi = f.vector(value, where, 2)
    if lo > hi:
        raise f.error(where, f"expected [lo, hi] with lo <= hi, got {value!r}")
    if positive and lo <= 0:
        raise f.error(where, f"must be > 0, got {value!r}")
    return lo, hi


def _bool(f: _Fields, value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise f.error(where, f"must be true or false, got {value!r}")
    return value


def _object_id(f: _Fields, value: Any, where: str, scene: Scene, *, dynamic: bool = True) -> str:
    if not isinstance(value, str) or value not in scene.object_ids:
        raise f.error(where, f"unknown object {value!r} (scene objects: {', '.join(scene.object_ids)})")
    if dynamic and scene.get(value).static:
        raise f.error(where, f"object {value!r} is static")
    return value


def _parse_perception(f: _Fields, raw: Any, where: str) -> PerceptionConfig:
    raw = f.mapping(raw, where)
    names = set(PerceptionConfig.__dataclass_fields__)
    f.only(raw, names, where)
    kw: dict[str, Any] = {}
    for key, value in raw.items():
        w = f"{where}.{key}"
        if key == "height_offset":
            kw[key] = ((f.number(value, w),) * 2 if not isinstance(value, (list, tuple))
                       else _range(f, value, w))
        elif key == "fixed_orientation":
            if isinstance(value, bool):
                kw[key] = ("*",) if value else ()
            elif isinstance(value, list) and all(isinstance(v, str) for v in value):
                kw[key] = tuple(value)
            else:
                raise f.error(w, f"must be true, false or a list of object ids, got {value!r}")
        elif key in ("report_static", "hands_tracked"):
            kw[key] = _bool(f, value, w)
        elif key == "points_per_object":
            if isinstance(value, bool) or not isinstance(value, int):
                raise f.error(w, f"must be an integer, got {value!r}")
            kw[key] = value
        else:
            kw[key] = f.number(value, w)
    try:
        return PerceptionConfig(**kw)
    except ValueError as exc:
        field_name = str(exc).split(":", 1)[0].split(".", 1)[-1]
        raise f.error(f"{where}.{field_name}", str(exc).split(":", 1)[-1].strip()) from None


def _parse_target(f: _Fields, raw: Any, where: str, scene: Scene) -> HandTarget:
    if isinstance(raw, dict):
        f.only(raw, {"object", "offset"}, where)
        if "object" not in raw:
            raise f.error(where, "missing field 'object'")
        oid = _object_id(f, raw["object"], f"{where}.object", scene, dynamic=False)
        offset = f.vector(raw.get("offset", [0, 0, 0]), f"{where}.offset", 3)
        return HandTarget(object=oid, offset=offset)
    return HandTarget(position=f.vector(raw, where, 3))


def _parse_hand(f: _Fields, raw: Any, scene: Scene, duration: float) -> HandSpec:
    raw = f.mapping(raw, "hand")
    f.only(raw, _HAND, "hand")
    if "start" not in raw:
        raise f.error("hand", "missing field 'start'")
    kw: dict[str, Any] = {"start": f.vector(raw["start"], "hand.start", 3)}
    if "rpy" in raw:
        kw["rpy_deg"] = f.vector(raw["rpy"], "hand.rpy", 3)
    for key in ("radius", "mass", "max_force"):
        if key in raw:
            kw[key] = f.number(raw[key], f"hand.{key}", positive=True)
    if "collide" in raw:
        kw["collide"] = _bool(f, raw["collide"], "hand.collide")
    held = None
    if raw.get("holding") is not None:
        held = kw["holding"] = _object_id(f, raw["holding"], "hand.holding", scene)
    script = raw.get("script", [])
    if not isinstance(script, list):
        raise f.error("hand.script", "must be a list of waypoints")
    waypoints = []
    last_t = 0.0
    for k, step in enumerate(script):
        w = f"hand.script[{k}]"
        step = f.mapping(step, w)
        f.only(step, _WAYPOINT, w)
        if "t" not in step:
            raise f.error(w, "missing field 't'")
        t = f.number(step["t"], f"{w}.t", nonneg=True)
        if t < last_t:
            raise f.error(f"{w}.t", f"times must not decrease ({t} after {last_t})")
        if t > duration:
            raise f.error(f"{w}.t", f"after the end of the scenario (duration {duration})")
        last_t = t
        if "to" in step and "by" in step:
            raise f.error(w, "give either 'to' or 'by', not both")
        wp: dict[str, Any] = {"t": t}
        if "to" in step:
            wp["to"] = _parse_target(f, step["to"], f"{w}.to", scene)
        elif "by" in step:
            wp["to"] = HandTarget(by=f.vector(step["by"], f"{w}.by", 3))
        if "rpy" in step:
            wp["rpy_deg"] = f.vector(step["rpy"], f"{w}.rpy", 3)
        if "collide" in step:
            wp["collide"] = _bool(f, step["collide"], f"{w}.collide")
        if "grasp" in step:
            if held is not None:
                raise f.error(f"{w}.grasp", f"the hand already holds {held!r}")
            held = wp["grasp"] = _object_id(f, step["grasp"], f"{w}.grasp", scene)
        if "release" in step:
            oid = _object_id(f, step["release"], f"{w}.release", scene)
            if held != oid:
                raise f.error(f"{w}.release", f"the hand does not hold {oid!r} here")
            wp["release"] = oid
            held = None
        waypoints.append(Waypoint(**wp))
    kw["script"] = tuple(waypoints)
    return HandSpec(**kw)


def _parse_randomize(f: _Fields, raw: Any, scene: Scene) -> Randomization:
    raw = f.mapping(raw, "randomize")
    f.only(raw, {"objects", "timing"}, "randomize")
    kw: dict[str, Any] = {}
    if "timing" in raw:
        timing = f.mapping(raw["timing"], "randomize.timing")
        f.only(timing, {"scale", "delay"}, "randomize.timing")
        if "scale" in timing:
            kw["time_scale"] = _range(f, timing["scale"], "randomize.timing.scale", positive=True)
        if "delay" in timing:
            kw["delay"] = _range(f, timing["delay"], "randomize.timing.delay")
            if kw["delay"][0] < 0:
                raise f.error("randomize.timing.delay", "must be >= 0")
    objs = []
    for oid, spec in f.mapping(raw.get("objects", {}), "randomize.objects").items():
        w = f"randomize.objects.{oid}"
        _object_id(f, oid, w, scene)
        spec = f.mapping(spec, w)
        f.only(spec, set(_OBJ_RANDOM), w)
        o: dict[str, Any] = {"id": oid}
        for key in _OBJ_RANDOM:
            if key not in spec:
                continue
            v = spec[key]
            if key == "position":
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    r = f.number(v, f"{w}.position", nonneg=True)
                    o["position"] = ((-r, r), (-r, r), (0.0, 0.0))
                else:
                    if not isinstance(v, list) or len(v) != 3:
                        raise f.error(f"{w}.position", "must be a number or three [lo, hi] ranges")
                    o["position"] = tuple(_range(f, v[i], f"{w}.position[{i}]") for i in range(3))
            elif key == "yaw":
                o["yaw_deg"] = _range(f, v, f"{w}.yaw")
            elif key in ("size", "mass"):
                o[key] = _range(f, v, f"{w}.{key}", positive=True)
            else:
                lo_hi = _range(f, v, f"{w}.{key}")
                if lo_hi[0] < 0:
                    raise f.error(f"{w}.{key}", "must be >= 0")
                o[key] = lo_hi
        objs.append(ObjectRandomization(**o))
    kw["objects"] = tuple(objs)
    return Randomization(**kw)


def scenario_from_dict(data: Any, *, path: str | None = None, lines: dict[str, int] | None = None,
                       builtin: bool = False) -> Scenario:
    """Validate a parsed scenario mapping (see :mod:`experiments.scenarios` for the format)."""
    lines = lines or {}
    f = _Fields(path, lines)
    data = f.mapping(data, "")
    f.only(data, _TOP, "")
    name = data.get("name", Path(path).stem if path else "scenario")
    if not isinstance(name, str) or not name:
        raise f.error("name", f"must be a non-empty string, got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise f.error("description", "must be a string")
    if "duration" not in data:
        raise f.error("", "missing field 'duration'")
    duration = f.number(data["duration"], "duration", positive=True)
    if duration > 600:
        raise f.error("duration", "must be at most 600 s")
    settle = f.number(data.get("settle", 0.3), "settle", nonneg=True)
    if "scene" not in data:
        raise f.error("", "missing field 'scene'")
    raw_scene = dict(f.mapping(data["scene"], "scene"))
    raw_scene.setdefault("name", name)
    sub = {k[len("scene."):]: v for k, v in lines.items() if k.startswith("scene.")}
    sub[""] = lines.get("scene", 1)
    try:
        scene = scene_from_dict(raw_scene, path=path, lines=sub,
                                base_dir=Path(path).parent if path else None)
    except SceneError as exc:
        fld = f"scene.{exc.field}" if exc.field else "scene"
        raise SceneError(exc.message, path=exc.path, line=exc.line, field=fld) from None
    hand = _parse_hand(f, data["hand"], scene, duration) if data.get("hand") is not None else None
    torso = None
    if data.get("torso") is not None:
        t = f.mapping(data["torso"], "torso")
        f.only(t, {"size", "position"}, "torso")
        f.require(t, ("size", "position"), "torso")
        torso = TorsoSpec(size=f.vector(t["size"], "torso.size", 3, positive=True),
                          position=f.vector(t["position"], "torso.position", 3))
    perception = _parse_perception(f, data.get("perception", {}) or {}, "perception")
    if perception.hands_tracked and hand is None:
        raise f.error("perception.hands_tracked", "the scenario has no hand to track")
    for oid in perception.fixed_orientation:
        if oid != "*" and oid not in scene.object_ids:
            raise f.error("perception.fixed_orientation", f"unknown object {oid!r}")
    randomize = _parse_randomize(f, data.get("randomize", {}) or {}, scene)
    return Scenario(name=name, scene=scene, duration=duration, description=description.strip(),
                    settle=settle, hand=hand, torso=torso, perception=perception,
                    randomize=randomize, source=path, builtin=builtin)
