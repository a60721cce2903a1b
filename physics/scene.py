"""Scene files: the static description of a tabletop (objects, shapes, physical parameters, camera).

A scene is a YAML (or JSON) file; see the README for the format. :func:`load_scene` validates it and
returns a frozen :class:`Scene`. Every problem is reported as a :class:`~physics.errors.SceneError`
naming the file, the line and the field.

Units: metres, kilograms, seconds; quaternions ``(x, y, z, w)``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from .fields import _Fields, read_yaml_with_lines
from .hollow import urdf_is_open
from .transforms import quat_rotate

PYBULLET_DATA_PREFIX = "pybullet_data://"
SHAPES = ("urdf", "box", "sphere", "cylinder", "container")
SCENE_FORMAT_VERSION = 1


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a scene.

    ``shape`` is one of ``urdf``, ``box`` (``size`` = full extents), ``sphere`` (``radius``),
    ``cylinder`` (``radius``, ``height``, axis along z) or ``container`` (an open-top box of five
    walls; ``size`` = outer extents, ``wall`` = wall thickness). Primitive and container frames are
    at the centre of their bounding box. ``position`` / ``orientation`` give the initial (for static
    objects: fixed) pose, or are ``None`` when the object is unknown until first perceived.
    ``mass`` ``None`` keeps the URDF's mass (primitives then default to 0.1 kg). ``hollow``: whether
    the object may contain others (isIn); ``None`` (the default) decides it from the shape, static
    or not: open containers may, solid primitives may not, and a URDF may when its geometry is open
    (:func:`physics.hollow.urdf_is_open`: a tray, a mug, but not a table, a cube or a duck).
    """

    id: str
    shape: str
    urdf: str | None = None
    size: tuple[float, float, float] | None = None
    radius: float | None = None
    height: float | None = None
    wall: float | None = None
    scale: float = 1.0
    position: tuple[float, float, float] | None = None
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    static: bool = False
    mass: float | None = None
    friction: float | None = None
    rolling_friction: float | None = None
    spinning_friction: float | None = None
    restitution: float | None = None
    color: tuple[float, float, float, float] | None = None
    hollow: bool | None = None

    @property
    def may_contain(self) -> bool:
        """Whether this object may contain others (see ``hollow``)."""
        if self.hollow is not None:
            return self.hollow
        if self.shape == "urdf":
            return urdf_is_open(self.urdf, self.scale)
        return self.shape == "container"


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera looking from ``position`` at ``target`` (metres), with a vertical field of
    view ``fov_deg`` (degrees), ``aspect`` = width / height, and clipping distances ``near``/``far``."""

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 60.0
    aspect: float = 4.0 / 3.0
    near: float = 0.1
    far: float = 4.0


@dataclass(frozen=True)
class PersonSpec:
    """A person the robot works with: ``id`` (the owner of the tracked hands named ``"<id>/..."``),
    an optional ``head`` camera (what the person sees) and the ``reach`` radius (m) around the
    person's tracked hands (or head, when no hand is tracked) within which an object is reachable."""

    id: str
    head: CameraSpec | None = None
    reach: float = 0.7


WORKSPACE_MARGIN = 3.0
"""m: the default workspace extends this far beyond the scene's objects and camera (see
:meth:`Scene.workspace_bounds`)."""


@dataclass(frozen=True)
class Scene:
    """A validated scene: name, optional floor plane at z = 0, optional camera, objects in order, and
    an optional ``workspace`` box ``((x, y, z) min, (x, y, z) max)`` in metres: detections outside it
    are physically absurd and rejected (see :meth:`workspace_bounds` for the default)."""

    name: str
    objects: tuple[ObjectSpec, ...]
    floor: bool = True
    camera: CameraSpec | None = None
    source: str | None = None
    workspace: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    person: PersonSpec | None = None

    def workspace_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The box ``(lo (3,), hi (3,))`` (m) where perception can be believed: the scene's
        ``workspace`` if given, else the box around the objects' given positions and the camera,
        :data:`WORKSPACE_MARGIN` wider on every side but the bottom, which is 0.5 m under the floor
        (with a floor; else the margin too)."""
        if self.workspace is not None:
            return np.array(self.workspace[0], dtype=float), np.array(self.workspace[1], dtype=float)
        pts = [o.position for o in self.objects if o.position is not None]
        if self.camera is not None:
            pts.append(self.camera.position)
        pts = np.array(pts, dtype=float).reshape(-1, 3) if pts else np.zeros((1, 3))
        lo, hi = pts.min(axis=0) - WORKSPACE_MARGIN, pts.max(axis=0) + WORKSPACE_MARGIN
        if self.floor:
            lo[2] = -0.5
        return lo, hi

    @property
    def object_ids(self) -> tuple[str, ...]:
        return tuple(o.id for o in self.objects)

    @property
    def hollow(self) -> tuple[bool, ...]:
        """Per object, whether it may contain others (:attr:`ObjectSpec.may_contain`)."""
        return tuple(o.may_contain for o in self.objects)

    def index(self, object_id: str) -> int:
        """Position of ``object_id`` in :attr:`objects`; ``KeyError`` if unknown."""
        for i, o in enumerate(self.objects):
            if o.id == object_id:
                return i
        raise KeyError(object_id)

    def get(self, object_id: str) -> ObjectSpec:
        return self.objects[self.index(object_id)]

    def with_objects(self, objects) -> "Scene":
        return replace(self, objects=tuple(objects))

    def to_dict(self) -> dict[str, Any]:
        """The scene in the file format (round-trips through :func:`scene_from_dict`)."""
        return scene_to_dict(self)


def resolve_urdf(ref: str, scene_dir: Path | None) -> str:
    """Absolute path of a URDF reference: ``pybullet_data://...``, absolute, or relative to the scene."""
    if ref.startswith(PYBULLET_DATA_PREFIX):
        import pybullet_data

        return os.path.join(pybullet_data.getDataPath(), ref[len(PYBULLET_DATA_PREFIX):])
    p = Path(ref)
    if not p.is_absolute() and scene_dir is not None:
        p = scene_dir / p
    return str(p)


_OBJECT_FIELDS = {"id", "urdf", "box", "sphere", "cylinder", "container", "pose", "static", "mass",
                  "friction", "rolling_friction", "spinning_friction", "restitution", "color", "scale",
                  "hollow"}


def _parse_object(f: _Fields, raw: Any, where: str, scene_dir: Path | None) -> ObjectSpec:
    raw = f.mapping(raw, where)
    f.only(raw, _OBJECT_FIELDS, where)
    if "id" not in raw:
        raise f.error(where, "missing field 'id'")
    oid = raw["id"]
    if not isinstance(oid, str) or not oid or oid == "floor":
        raise f.error(f"{where}.id", f"must be a non-empty string other than 'floor', got {oid!r}")
    geometry = [k for k in ("urdf", "box", "sphere", "cylinder", "container") if k in raw]
    if len(geometry) != 1:
        raise f.error(where, "needs exactly one geometry: urdf, box, sphere, cylinder or container "
                             f"(got {geometry or 'none'})")
    shape = geometry[0]
    kw: dict[str, Any] = {"id": oid, "shape": shape}
    if shape == "urdf":
        ref = raw["urdf"]
        if not isinstance(ref, str) or not ref:
            raise f.error(f"{where}.urdf", f"must be a path, got {ref!r}")
        resolved = resolve_urdf(ref, scene_dir)
        if not os.path.isfile(resolved):
            raise f.error(f"{where}.urdf", f"URDF file not found: {ref} (looked for {resolved})")
        kw["urdf"] = resolved
    else:
        block = f.mapping(raw[shape], f"{where}.{shape}")
        w = f"{where}.{shape}"
        if shape == "box":
            f.only(block, {"size"}, w)
            kw["size"] = f.vector(block.get("size"), f"{w}.size", 3, positive=True)
        elif shape == "sphere":
            f.only(block, {"radius"}, w)
            kw["radius"] = f.number(block.get("radius"), f"{w}.radius", positive=True)
        elif shape == "cylinder":
            f.only(block, {"radius", "height"}, w)
            kw["radius"] = f.number(block.get("radius"), f"{w}.radius", positive=True)
            kw["height"] = f.number(block.get("height"), f"{w}.height", positive=True)
        else:
            f.only(block, {"size", "wall"}, w)
            size = f.vector(block.get("size"), f"{w}.size", 3, positive=True)
            wall = f.number(block.get("wall", 0.01), f"{w}.wall", positive=True)
            if 2 * wall >= min(size[0], size[1]) or wall >= size[2]:
                raise f.error(f"{w}.wall", f"wall {wall} too thick for size {list(size)}")
            kw["size"], kw["wall"] = size, wall
    if "pose" in raw:
        pose = f.mapping(raw["pose"], f"{where}.pose")
        f.only(pose, {"position", "orientation"}, f"{where}.pose")
        if "position" not in pose:
            raise f.error(f"{where}.pose", "missing field 'position'")
        kw["position"] = f.vector(pose["position"], f"{where}.pose.position", 3)
        if "orientation" in pose:
            kw["orientation"] = f.quaternion(pose["orientation"], f"{where}.pose.orientation")
    static = raw.get("static", False)
    if not isinstance(static, bool):
        raise f.error(f"{where}.static", f"must be true or false, got {static!r}")
    kw["static"] = static
    if "hollow" in raw:
        if not isinstance(raw["hollow"], bool):
            raise f.error(f"{where}.hollow", f"must be true or false, got {raw['hollow']!r}")
        kw["hollow"] = raw["hollow"]
    if static and kw.get("position") is None:
        raise f.error(where, "a static object needs a pose")
    if "mass" in raw:
        kw["mass"] = f.number(raw["mass"], f"{where}.mass", positive=True)
    for key in ("friction", "rolling_friction", "spinning_friction", "restitution"):
        if key in raw:
            kw[key] = f.number(raw[key], f"{where}.{key}", nonneg=True)
    if "scale" in raw:
        kw["scale"] = f.number(raw["scale"], f"{where}.scale", positive=True)
    if "color" in raw:
        c = raw["color"]
        if isinstance(c, (list, tuple)) and len(c) == 3:
            c = list(c) + [1.0]
        kw["color"] = f.vector(c, f"{where}.color", 4)
    return ObjectSpec(**kw)


def scene_from_dict(data: Any, *, path: str | None = None, lines: dict[str, int] | None = None,
                    base_dir: str | Path | None = None) -> Scene:
    """Validate a parsed scene mapping. ``base_dir`` resolves relative URDF paths."""
    f = _Fields(path, lines or {})
    data = f.mapping(data, "")
    f.only(data, {"name", "floor", "camera", "objects", "version", "workspace", "person"}, "")
    version = data.get("version", SCENE_FORMAT_VERSION)
    if version != SCENE_FORMAT_VERSION:
        raise f.error("version", f"unsupported scene format version {version!r} "
                                 f"(this release reads {SCENE_FORMAT_VERSION})")
    name = data.get("name", Path(path).stem if path else "scene")
    if not isinstance(name, str):
        raise f.error("name", f"must be a string, got {name!r}")
    floor = data.get("floor", True)
    if not isinstance(floor, bool):
        raise f.error("floor", f"must be true or false, got {floor!r}")
    camera = None
    if data.get("camera") is not None:
        camera = parse_camera(f, data["camera"], "camera")
    raw_objects = data.get("objects")
    if not isinstance(raw_objects, list) or not raw_objects:
        raise f.error("objects", "must be a non-empty list of objects")
    base = Path(base_dir) if base_dir is not None else (Path(path).parent if path else None)
    objects = []
    seen: set[str] = set()
    for i, raw in enumerate(raw_objects):
        spec = _parse_object(f, raw, f"objects[{i}]", base)
        if spec.id in seen:
            raise f.error(f"objects[{i}].id", f"duplicate object id {spec.id!r}")
        seen.add(spec.id)
        objects.append(spec)
    workspace = None
    if data.get("workspace") is not None:
        ws = f.mapping(data["workspace"], "workspace")
        f.only(ws, {"min", "max"}, "workspace")
        f.require(ws, ("min", "max"), "workspace")
        lo, hi = f.vector(ws["min"], "workspace.min", 3), f.vector(ws["max"], "workspace.max", 3)
        if not all(a < b for a, b in zip(lo, hi)):
            raise f.error("workspace.max", f"must be greater than workspace.min on every axis, got {hi} and {lo}")
        workspace = (lo, hi)
    person = None
    if data.get("person") is not None:
        pd = f.mapping(data["person"], "person")
        f.only(pd, {"id", "head", "reach"}, "person")
        pid = pd.get("id", "human")
        if not isinstance(pid, str) or not pid:
            raise f.error("person.id", f"must be a non-empty string, got {pid!r}")
        head = parse_camera(f, pd["head"], "person.head", orientation=True) if pd.get("head") is not None else None
        person = PersonSpec(pid, head, f.number(pd.get("reach", 0.7), "person.reach", positive=True))
    return Scene(name=name, objects=tuple(objects), floor=floor, camera=camera, source=path, workspace=workspace,
                 person=person)


def parse_camera(f: "_Fields", value: Any, where: str, *, extra: set[str] = frozenset(),
                 orientation: bool = False) -> CameraSpec:
    """Validate a camera mapping at field ``where`` (the scene's ``camera``, a frame's
    ``cameras[i]``): ``position`` and ``target`` (or, with ``orientation=True``, an ``orientation``
    quaternion x, y, z, w of the camera's optical frame: z forward, y down), optional ``up``,
    ``fov_deg``, ``aspect``, ``near``, ``far``; ``extra``: further keys allowed (not read here)."""
    c = f.mapping(value, where)
    allowed = {"position", "target", "up", "fov_deg", "aspect", "near", "far"} | set(extra)
    if orientation:
        allowed.add("orientation")
    f.only(c, allowed, where)
    if "position" not in c:
        raise f.error(where, "missing field 'position'")
    position = f.vector(c["position"], f"{where}.position", 3)
    up = f.vector(c.get("up", [0, 0, 1]), f"{where}.up", 3)
    if orientation and "orientation" in c:
        if "target" in c:
            raise f.error(f"{where}.orientation", "give either target or orientation, not both")
        q = f.quaternion(c["orientation"], f"{where}.orientation")
        fwd, down = quat_rotate(np.array(q), np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]))
        target = tuple(float(v) for v in np.asarray(position) + fwd)
        if "up" not in c:
            up = tuple(float(-v) for v in down)
    elif "target" not in c:
        raise f.error(where, "missing field 'target'" + (" (or orientation)" if orientation else ""))
    else:
        target = f.vector(c["target"], f"{where}.target", 3)
    camera = CameraSpec(
        position=position, target=target, up=up,
        fov_deg=f.number(c.get("fov_deg", 60.0), f"{where}.fov_deg", positive=True),
        aspect=f.number(c.get("aspect", 4 / 3), f"{where}.aspect", positive=True),
        near=f.number(c.get("near", 0.1), f"{where}.near", positive=True),
        far=f.number(c.get("far", 4.0), f"{where}.far", positive=True),
    )
    if camera.far <= camera.near:
        raise f.error(f"{where}.far", f"must be greater than {where}.near")
    if np.allclose(camera.position, camera.target):
        raise f.error(f"{where}.target", f"must differ from {where}.position")
    return camera


def camera_to_dict(c: CameraSpec) -> dict[str, Any]:
    """A camera as the file formats write it (look-at form)."""
    return {"position": list(c.position), "target": list(c.target), "up": list(c.up),
            "fov_deg": c.fov_deg, "aspect": c.aspect, "near": c.near, "far": c.far}


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file (YAML or JSON). Raises :class:`SceneError`."""
    data, lines = read_yaml_with_lines(path)
    return scene_from_dict(data, path=str(path), lines=lines)


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """Serialise a scene to the file format. URDF paths inside pybullet_data are written portably."""
    import pybullet_data

    data_dir = os.path.realpath(pybullet_data.getDataPath())
    out: dict[str, Any] = {"version": SCENE_FORMAT_VERSION, "name": scene.name, "floor": scene.floor}
    if scene.camera is not None:
        out["camera"] = camera_to_dict(scene.camera)
    objs = []
    for o in scene.objects:
        d: dict[str, Any] = {"id": o.id}
        if o.shape == "urdf":
            real = os.path.realpath(o.urdf)
            d["urdf"] = (PYBULLET_DATA_PREFIX + os.path.relpath(real, data_dir)
                         if real.startswith(data_dir + os.sep) else o.urdf)
        elif o.shape == "box":
            d["box"] = {"size": list(o.size)}
        elif o.shape == "sphere":
            d["sphere"] = {"radius": o.radius}
        elif o.shape == "cylinder":
            d["cylinder"] = {"radius": o.radius, "height": o.height}
        else:
            d["container"] = {"size": list(o.size), "wall": o.wall}
        if o.position is not None:
            d["pose"] = {"position": [float(v) for v in o.position],
                         "orientation": [float(v) for v in o.orientation]}
        if o.static:
            d["static"] = True
        if o.hollow is not None:
            d["hollow"] = o.hollow
        for key in ("mass", "friction", "rolling_friction", "spinning_friction", "restitution"):
            v = getattr(o, key)
            if v is not None:
                d[key] = float(v)
        if o.scale != 1.0:
            d["scale"] = o.scale
        if o.color is not None:
            d["color"] = list(o.color)
        objs.append(d)
    out["objects"] = objs
    if scene.workspace is not None:
        out["workspace"] = {"min": list(scene.workspace[0]), "max": list(scene.workspace[1])}
    if scene.person is not None:
        out["person"] = {"id": scene.person.id, "reach": scene.person.reach}
        if scene.person.head is not None:
            out["person"]["head"] = camera_to_dict(scene.person.head)
    return out
