"""The MuJoCo model of a scenario's variant: its MJCF document (:func:`mjcf`), built from the scene's
objects, the scripted hand and their contact parameters, for
:class:`~experiments.simulation.mujoco_truth.MujocoGroundTruth`.

The MuJoCo world (:func:`mjcf`):

* primitives map one to one (a cylinder's axis along z, as in the scene); an open container is its
  five boxes, as in :mod:`physics.bodies`; a URDF's ``<collision>`` elements of its one link become
  boxes, spheres, cylinders and meshes, a mesh one convex geom per object (``o``) of its OBJ file
  (:func:`obj_parts`: pybullet_data's mug and duck are several convex parts; the tray is boxes), so
  that what is hollow stays hollow. ``globalScaling`` (the scene's ``scale``) scales every element;
* masses are the scene's (or the URDF's); inertia follows from the geometry at uniform density
  (MuJoCo's own computation); the centre of mass is where a URDF states it (as in pybullet: it is
  part of the object's description, pybullet_data's duck has it 2 cm off its centroid), else at
  the geometry's centroid;
* the hand is a dynamic sphere (gravity compensated) welded to a mocap body that follows the script;
  a grasp switches on a weld between the hand and the object at their relative pose of the moment, a
  release switches it off. The hand collides with objects only while the script says it pushes
  (``collide``), and never with an object it holds (contact bits, :data:`OBJECT_BITS`);
* the torso is not in it, only in the truth's pybullet mirror: it hides things from the camera and
  collides with nothing, as in the Bullet truth.

Contact parameters (:func:`contact_attributes`): the scene's per-object values mean what they say
physically, not what imitates Bullet. ``friction`` is MuJoCo's sliding friction, ``spinning_friction``
its torsional and ``rolling_friction`` its rolling friction (both lengths, m); unstated values are
:data:`DEFAULT_FRICTION`, :data:`DEFAULT_SPINNING` and :data:`DEFAULT_ROLLING`. MuJoCo combines two
geoms' frictions by their maximum (Bullet by their product). ``restitution`` ``e`` becomes the damping
ratio of the contact's spring, ``zeta = -ln(e) / sqrt(pi^2 + ln(e)^2)`` (a damped linear spring
bounces back with ``e = exp(-zeta pi / sqrt(1 - zeta^2))``), with time constant
:data:`CONTACT_TIME`; ``e = 0`` is critical damping (MuJoCo's default). Two geoms' references are
averaged.

Quaternions in MuJoCo are ``(w, x, y, z)``; everything this module returns uses ``(x, y, z, w)``.
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from experiments.simulation.variants import Variant
from physics.bodies import DEFAULT_PRIMITIVE_MASS, DEFAULT_URDF_MASS
from physics.errors import SceneError
from physics.scene import ObjectSpec, Scene

TIME_STEP = 1.0 / 480.0
"""s: MuJoCo's integration step (a divisor of the 30 Hz and 240 Hz clocks of the scenarios)."""
CONTACT_TIME = 0.01
"""s: time constant of MuJoCo's soft contacts (stiff, as a rigid tabletop object's)."""
WELD_TIME = 0.01
"""s: time constant of the hand's welds (to its scripted target, and to a grasped object)."""
DEFAULT_FRICTION = 0.5
"""Sliding friction of an object whose scene states none (wood, plastic, ceramic on wood)."""
DEFAULT_SPINNING = 0.001
"""m: torsional friction of an object whose scene states none."""
DEFAULT_ROLLING = 0.0001
"""m: rolling friction of an object whose scene states none (MuJoCo's default)."""
MAX_RESTITUTION = 0.95
"""Restitutions are capped here (a scaled one may exceed 1; nothing real bounces back whole)."""
OBJECT_BITS = (1, 3)
"""(contype, conaffinity) of scene geoms and the floor: bit 1 collides them with each other, bit 2
lets the hand (contype 2 while it pushes, 0 otherwise; conaffinity 0) touch them. A held object's
conaffinity drops bit 2."""


# --------------------------------------------------------------------------------------------------
# geometry


def obj_parts(path: str) -> list[np.ndarray]:
    """Vertices ``(n, 3)`` of each object (``o``, or ``g`` where there is no ``o``) of a Wavefront
    OBJ file that has faces, in file order; a file with neither is one part."""
    vertices: list[tuple[float, float, float]] = []
    parts: list[list[int]] = [[]]
    marker = None
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    if any(line.startswith("o ") for line in lines):
        marker = "o "
    elif any(line.startswith("g ") for line in lines):
        marker = "g "
    for line in lines:
        if line.startswith("v "):
            x, y, z = (float(v) for v in line.split()[1:4])
            vertices.append((x, y, z))
        elif marker is not None and line.startswith(marker):
            if parts[-1]:
                parts.append([])
        elif line.startswith("f "):
            for token in line.split()[1:]:
                k = int(token.split("/")[0])
                parts[-1].append(k - 1 if k > 0 else len(vertices) + k)
    v = np.asarray(vertices, dtype=float)
    out = [v[np.unique(p)] for p in parts if p]
    return out or [v]


def _origin(element: ET.Element | None, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Position ``(3,)`` (m, scaled) and quaternion ``(4,)`` (x, y, z, w) of a URDF ``<origin>``."""
    if element is None:
        return np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    xyz = np.array([float(v) for v in element.get("xyz", "0 0 0").split()]) * scale
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()]
    return xyz, Rotation.from_euler("xyz", rpy).as_quat()


def urdf_geoms(path: str, scale: float = 1.0) -> tuple[list[dict], float | None]:
    """The collision geometry of a one-link URDF as geoms ``{"type", "size" | "vertices", "pos",
    "quat"}`` (MuJoCo sizes: half extents, radius, radius and half height; ``quat`` x, y, z, w;
    everything scaled by ``scale``) and the mass its ``<inertial>`` states (None without one)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise SceneError(f"cannot read URDF {path}: {exc}", path=path) from None
    links = [link for link in root.iter("link") if link.find("collision") is not None]
    if len(links) > 1:
        raise SceneError(f"the MuJoCo truth loads URDFs of one link with collisions; {path} has "
                         f"{len(links)}", path=path)
    geoms: list[dict] = []
    base = os.path.dirname(os.path.abspath(path))
    for col in (links[0].findall("collision") if links else []):
        pos, quat = _origin(col.find("origin"), scale)
        geo = col.find("geometry")
        shape = next(iter(geo), None) if geo is not None else None
        if shape is None:
            continue
        if shape.tag == "box":
            size = np.array([float(v) for v in shape.get("size").split()]) * scale / 2
            geoms.append({"type": "box", "size": size, "pos": pos, "quat": quat})
        elif shape.tag == "sphere":
            geoms.append({"type": "sphere", "size": np.array([float(shape.get("radius")) * scale]),
                          "pos": pos, "quat": quat})
        elif shape.tag == "cylinder":
            geoms.append({"type": "cylinder", "size": np.array([float(shape.get("radius")) * scale,
                                                                 float(shape.get("length")) * scale / 2]),
                          "pos": pos, "quat": quat})
        elif shape.tag == "mesh":
            name = shape.get("filename", "")
            file = name if os.path.isabs(name) else os.path.join(base, name)
            mesh_scale = np.array([float(v) for v in shape.get("scale", "1 1 1").split()]) * scale
            if not os.path.exists(file):
                raise SceneError(f"mesh {name} of URDF {path} not found", path=path)
            for part in obj_parts(file):
                geoms.append({"type": "mesh", "vertices": part * mesh_scale, "pos": pos, "quat": quat})
        else:
            raise SceneError(f"URDF {path}: collision geometry <{shape.tag}> is not supported by the "
                             "MuJoCo truth", path=path)
    mass = None
    inertial = links[0].find("inertial") if links else None
    if inertial is not None and inertial.find("mass") is not None:
        mass = float(inertial.find("mass").get("value"))
    return geoms, mass


def object_geoms(spec: ObjectSpec) -> tuple[list[dict], float]:
    """Geoms of a scene object in its link frame (see :func:`urdf_geoms`) and its mass (kg; 0 for a
    static object)."""
    ident = np.array([0.0, 0.0, 0.0, 1.0])
    if spec.shape == "box":
        geoms = [{"type": "box", "size": np.asarray(spec.size, float) / 2, "pos": np.zeros(3), "quat": ident}]
    elif spec.shape == "sphere":
        geoms = [{"type": "sphere", "size": np.array([spec.radius]), "pos": np.zeros(3), "quat": ident}]
    elif spec.shape == "cylinder":
        geoms = [{"type": "cylinder", "size": np.array([spec.radius, spec.height / 2]), "pos": np.zeros(3),
                  "quat": ident}]
    elif spec.shape == "container":  # the five boxes of physics.bodies.collision_shape
        sx, sy, sz = spec.size
        w = spec.wall
        hw, zw = (sz - w) / 2, w / 2
        half = [[sx / 2, sy / 2, w / 2], [w / 2, sy / 2, hw], [w / 2, sy / 2, hw],
                [sx / 2 - w, w / 2, hw], [sx / 2 - w, w / 2, hw]]
        centres = [[0, 0, -sz / 2 + w / 2], [sx / 2 - w / 2, 0, zw], [-sx / 2 + w / 2, 0, zw],
                   [0, sy / 2 - w / 2, zw], [0, -sy / 2 + w / 2, zw]]
        geoms = [{"type": "box", "size": np.array(h, float), "pos": np.array(c, float), "quat": ident}
                 for h, c in zip(half, centres)]
    else:
        geoms, urdf_mass = _urdf_geoms_cached(spec.urdf, float(spec.scale))
        if spec.static:
            return geoms, 0.0
        mass = spec.mass if spec.mass is not None else (urdf_mass if urdf_mass and urdf_mass > 0
                                                         else DEFAULT_URDF_MASS)
        return geoms, float(mass)
    if spec.static:
        return geoms, 0.0
    return geoms, float(spec.mass if spec.mass is not None else DEFAULT_PRIMITIVE_MASS)


@lru_cache(maxsize=64)
def _urdf_geoms_cached(path: str, scale: float):
    return urdf_geoms(path, scale)


def urdf_centre_of_mass(path: str, scale: float = 1.0) -> np.ndarray | None:
    """The centre of mass ``(3,)`` (m, scaled, in the link frame) that a one-link URDF's
    ``<inertial><origin xyz>`` states (the link's origin when the origin is omitted); None without
    an ``<inertial>``. Part of the object's description, as its mass is: pybullet puts the centre of
    mass there (and computes the inertia from the collision shapes); so does the MuJoCo truth."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise SceneError(f"cannot read URDF {path}: {exc}", path=path) from None
    links = [link for link in root.iter("link") if link.find("collision") is not None]
    inertial = links[0].find("inertial") if links else None
    if inertial is None:
        return None
    return _origin(inertial.find("origin"), scale)[0]


# --------------------------------------------------------------------------------------------------
# the MJCF document


def restitution_damping(e: float) -> float:
    """Damping ratio of a linear spring contact that bounces back with restitution ``e`` (0 <= e < 1):
    ``-ln(e) / sqrt(pi^2 + ln(e)^2)``; 1 (critical damping) for ``e = 0``."""
    e = min(max(float(e), 0.0), MAX_RESTITUTION)
    if e <= 0.0:
        return 1.0
    ln = math.log(e)
    return -ln / math.sqrt(math.pi ** 2 + ln ** 2)


def contact_attributes(spec: ObjectSpec) -> str:
    """MJCF attributes of an object's geoms: friction (sliding, torsional, rolling), condim 6, solref
    (time constant, damping ratio of its restitution) and the contact bits (:data:`OBJECT_BITS`)."""
    slide = DEFAULT_FRICTION if spec.friction is None else spec.friction
    spin = DEFAULT_SPINNING if spec.spinning_friction is None else spec.spinning_friction
    roll = DEFAULT_ROLLING if spec.rolling_friction is None else spec.rolling_friction
    zeta = restitution_damping(spec.restitution or 0.0)
    return (f'friction="{_f(slide)} {_f(spin)} {_f(roll)}" condim="6" solref="{_f(CONTACT_TIME)} {_f(zeta)}" '
            f'contype="{OBJECT_BITS[0]}" conaffinity="{OBJECT_BITS[1]}"')


def _f(x: float) -> str:
    return repr(float(x))


def _v(values) -> str:
    return " ".join(_f(v) for v in np.asarray(values, dtype=float).ravel())


def _wxyz(q_xyzw) -> np.ndarray:
    q = np.asarray(q_xyzw, dtype=float)
    return np.array([q[3], q[0], q[1], q[2]])


def mjcf(variant: Variant, parked: np.ndarray, time_step: float = TIME_STEP, gravity: float = -9.81) -> str:
    """The MJCF document of ``variant``'s world: floor, objects (bodies ``obj<i>`` in scene order;
    static ones fixed), the hand (mocap ``hand_target``, dynamic ``hand`` welded to it by ``drive``)
    and one inactive weld ``grasp<i>`` per dynamic object. ``parked`` ``(M, 7)`` are the poses of
    objects the scene gives no pose (they are put there, collide with nothing and float)."""
    scene: Scene = variant.scene
    assets: list[str] = []
    bodies: list[str] = []
    for i, spec in enumerate(scene.objects):
        geoms, mass = object_geoms(spec)
        attrs = contact_attributes(spec)
        if spec.position is None:
            pos, quat = parked[i, :3], parked[i, 3:]
            attrs = attrs.replace(f'contype="{OBJECT_BITS[0]}" conaffinity="{OBJECT_BITS[1]}"',
                                  'contype="0" conaffinity="0"')
        else:
            pos, quat = np.asarray(spec.position, float), np.asarray(spec.orientation, float)
        lines = []
        for k, g in enumerate(geoms):
            frame = f'pos="{_v(g["pos"])}" quat="{_v(_wxyz(g["quat"]))}"'
            if g["type"] == "mesh":
                name = f"mesh{i}_{k}"
                assets.append(f'<mesh name="{name}" vertex="{_v(g["vertices"])}"/>')
                lines.append(f'<geom name="g{i}_{k}" type="mesh" mesh="{name}" {frame} {attrs}/>')
            else:
                lines.append(f'<geom name="g{i}_{k}" type="{g["type"]}" size="{_v(g["size"])}" {frame} {attrs}/>')
        head = f'<body name="obj{i}" pos="{_v(pos)}" quat="{_v(_wxyz(quat))}"'
        if spec.static:
            bodies.append(f'{head}>{"".join(lines)}</body>')
        else:
            grav = ' gravcomp="1"' if spec.position is None else ""
            bodies.append(f'{head}{grav}><freejoint name="free{i}"/>{"".join(lines)}</body>')
    hand = variant.scenario.hand
    welds: list[str] = []
    if hand is not None:
        start = _v(hand.start)
        q = _v(_wxyz(Rotation.from_euler("xyz", hand.rpy_deg, degrees=True).as_quat()))
        bodies.append(f'<body name="hand_target" mocap="true" pos="{start}" quat="{q}"/>')
        bodies.append(f'<body name="hand" pos="{start}" quat="{q}" gravcomp="1"><freejoint name="hand_free"/>'
                      f'<geom name="hand_geom" type="sphere" size="{_f(hand.radius)}" mass="{_f(hand.mass)}" '
                      f'contype="0" conaffinity="0" condim="3" friction="0.8 0.005 0.0001"/></body>')
        welds.append(f'<weld name="drive" body1="hand_target" body2="hand" solref="{_f(WELD_TIME)} 1"/>')
        for i, spec in enumerate(scene.objects):
            if not spec.static:
                welds.append(f'<weld name="grasp{i}" body1="hand" body2="obj{i}" active="false" '
                             f'solref="{_f(WELD_TIME)} 1"/>')
    floor = ""
    if scene.floor:
        floor = (f'<geom name="floor" type="plane" size="0 0 1" friction="{_f(DEFAULT_FRICTION)} '
                 f'{_f(DEFAULT_SPINNING)} {_f(DEFAULT_ROLLING)}" condim="6" contype="{OBJECT_BITS[0]}" '
                 f'conaffinity="{OBJECT_BITS[1]}"/>')
    return (f'<mujoco model="{scene.name}">'
            '<compiler angle="radian" inertiafromgeom="true" boundmass="1e-6" boundinertia="1e-9"/>'
            f'<option timestep="{_f(time_step)}" gravity="0 0 {_f(gravity)}" integrator="implicitfast" '
            'cone="elliptic" impratio="10"/>'
            f'<asset>{"".join(assets)}</asset>'
            f'<worldbody>{floor}{"".join(bodies)}</worldbody>'
            f'<equality>{"".join(welds)}</equality>'
            '</mujoco>')
