"""Collision-only copies of URDF files, for worlds that only simulate.

A pybullet DIRECT client still loads every ``<visual>`` of a URDF (meshes and textures, for its
software renderer): pybullet_data's table decodes its 0.9 MB texture at every load, and a
particle filter loads it once per particle. Physics never uses visuals, so worlds
load a copy of the URDF without its ``<visual>`` elements (mesh paths made absolute), written once
per process into a cache folder.

Inertia is unaffected: pybullet computes a missing ``<inertial>`` from the collision shapes, never
from visuals.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET

_CACHE: dict[tuple[str, float, int], str] = {}


def _cache_dir() -> str:
    path = os.path.join(tempfile.gettempdir(), f"scene-estimator-urdf-{os.getuid()}")
    os.makedirs(path, exist_ok=True)
    return path


def collision_only_urdf(path: str) -> str:
    """Path of a copy of the URDF file ``path`` without its ``<visual>`` elements.

    Relative mesh file names are made absolute (relative to ``path``'s folder), so the copy loads
    from anywhere. The copy is written once per process and content (keyed by the file's path,
    modification time and size) with an atomic rename, so that concurrent worker processes can share
    the cache folder. A file that cannot be parsed as XML is returned unchanged: pybullet then
    reports it as it would have.
    """
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError:
        return path
    key = (real, st.st_mtime, st.st_size)
    if key in _CACHE:
        return _CACHE[key]
    try:
        tree = ET.parse(real)
    except ET.ParseError:
        return path
    root = tree.getroot()
    for parent in root.iter():
        for visual in parent.findall("visual"):
            parent.remove(visual)
    base = os.path.dirname(real)
    for mesh in root.iter("mesh"):
        name = mesh.get("filename")
        if name and "://" not in name and not os.path.isabs(name):
            mesh.set("filename", os.path.join(base, name))
    digest = hashlib.sha1(repr(key).encode()).hexdigest()[:16]
    out = os.path.join(_cache_dir(), f"{os.path.splitext(os.path.basename(real))[0]}-{digest}.urdf")
    if not os.path.exists(out):
        fd, tmp = tempfile.mkstemp(suffix=".urdf", dir=os.path.dirname(out))
        with os.fdopen(fd, "wb") as fh:
            tree.write(fh)
        os.replace(tmp, out)
    _CACHE[key] = out
    return out
