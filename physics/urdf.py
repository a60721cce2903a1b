"""Copies of URDF files for worlds that only simulate, and for probing an object's shape.

A pybullet DIRECT client still loads every ``<visual>`` of a URDF (meshes and textures, for its
software renderer): pybullet_data's table decodes its 0.9 MB texture at every load, and a
particle filter loads it once per particle. Physics never uses visuals, so worlds
load a copy of the URDF without its ``<visual>`` elements (:func:`collision_only_urdf`, mesh paths
made absolute), written once per process into a cache folder.

Inertia is unaffected: pybullet computes a missing ``<inertial>`` from the collision shapes, never
from visuals.

A URDF's collision shape is often coarser than its look: pybullet_data's mug collides as a closed
cylinder (a convex hull) while its visual mesh is open. :func:`visual_geometry_urdf` writes a copy
whose collision shapes are the visual geometry, meshes as concave triangle meshes, massless, for
:mod:`physics.hollow` to cast rays at.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET

_CACHE: dict[tuple[str, str, float, int], str] = {}
_REAL: dict[str, str] = {}  # a path as given -> the file it names (links resolved once per process)


def _cache_dir() -> str:
    path = os.path.join(tempfile.gettempdir(), f"scene-estimator-urdf-{os.getuid()}")
    os.makedirs(path, exist_ok=True)
    return path


def _strip_visuals(root: ET.Element) -> None:
    for parent in root.iter():
        for visual in parent.findall("visual"):
            parent.remove(visual)


def _visuals_as_collisions(root: ET.Element) -> None:
    for link in root.iter("link"):
        for collision in link.findall("collision"):
            link.remove(collision)
        for visual in link.findall("visual"):
            visual.tag = "collision"
            visual.set("concave", "yes")  # pybullet: a concave triangle mesh (for a static body)
            for material in visual.findall("material"):
                visual.remove(material)
        for inertial in link.findall("inertial"):
            for mass in inertial.findall("mass"):
                mass.set("value", "0")


_KINDS = {"collision": _strip_visuals, "visual": _visuals_as_collisions}


def _copy(path: str, kind: str) -> str:
    """Path of a copy of the URDF ``path`` changed by ``_KINDS[kind]``, relative mesh file names made
    absolute; written once per process and content (the file's path, resolved once per process,
    modification time and size)
    with an atomic rename, so that concurrent worker processes share the cache folder. A file that
    cannot be read or parsed as XML is returned unchanged: pybullet then reports it as it would have."""
    real = _REAL.get(path)
    if real is None:  # (resolving a path reads each of its folders: 0.1 ms, for every body of every copy)
        real = _REAL[path] = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError:
        return path
    key = (kind, real, st.st_mtime, st.st_size)
    if key in _CACHE:
        return _CACHE[key]
    try:
        tree = ET.parse(real)
    except ET.ParseError:
        return path
    root = tree.getroot()
    _KINDS[kind](root)
    base = os.path.dirname(real)
    for mesh in root.iter("mesh"):
        name = mesh.get("filename")
        if name and "://" not in name and not os.path.isabs(name):
            mesh.set("filename", os.path.join(base, name))
    digest = hashlib.sha1(repr(key[1:]).encode()).hexdigest()[:16]
    suffix = "" if kind == "collision" else f"-{kind}"
    out = os.path.join(_cache_dir(), f"{os.path.splitext(os.path.basename(real))[0]}-{digest}{suffix}.urdf")
    if not os.path.exists(out):
        fd, tmp = tempfile.mkstemp(suffix=".urdf", dir=os.path.dirname(out))
        with os.fdopen(fd, "wb") as fh:
            tree.write(fh)
        os.replace(tmp, out)
    _CACHE[key] = out
    return out


def collision_only_urdf(path: str) -> str:
    """Path of a copy of the URDF file ``path`` without its ``<visual>`` elements (see :func:`_copy`
    for the cache and for files that cannot be parsed)."""
    return _copy(path, "collision")


def visual_geometry_urdf(path: str) -> str:
    """Path of a copy of the URDF file ``path`` whose ``<collision>`` elements are its ``<visual>``
    geometry (same origins; meshes ``concave="yes"``, so pybullet keeps them as triangle meshes when
    the body is loaded with a fixed base) and whose links weigh nothing; for shape probes only."""
    return _copy(path, "visual")
