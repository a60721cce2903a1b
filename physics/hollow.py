"""Whether a URDF object is open (may contain others), decided from its geometry.

An object is *open* when, in its own frame (as the URDF is written, z up, at the scene's scale):

* a vertical ray down the middle of its bounding box (x, y centre) first meets the object at least
  :data:`MIN_DEPTH_FRACTION` of its height (and :data:`MIN_DEPTH` metres) below its top, and
* from the point halfway between that hit and the top, horizontal rays in :data:`N_SIDES` directions
  all meet the object within its bounding box: it has walls all round.

A tray, a bin, a mug or a bowl passes; a table (the ray hits its top), a cube, a ball, a duck (the ray
finds the dip of its back, but nothing encloses it) and a lego brick (its studs are no walls) do
not. The test is run on the URDF's collision shapes and on its visual geometry (meshes as concave
triangle meshes, :func:`physics.urdf.visual_geometry_urdf`), and either being open is enough:
pybullet_data's mug collides as a closed hull but looks, and is meant to be, a cup.

Each probe loads the URDF into a DIRECT pybullet client of its own (closed before returning); its
answer is cached per file (path, modification time, size) and scale, so a scene pays once per
process.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pybullet as pb

from .urdf import collision_only_urdf, visual_geometry_urdf

MIN_DEPTH_FRACTION = 0.25
"""The vertical ray's first hit must be at least this fraction of the object's height below its top."""
MIN_DEPTH = 0.005
"""m: ... and at least this far below it."""
N_SIDES = 8
"""Horizontal rays (evenly spread directions) that must all meet a wall."""

_CACHE: dict[tuple[str, float, int, float], bool] = {}


def _aabb(client: int, uid: int) -> tuple[np.ndarray, np.ndarray]:
    """World bounding box ``(lo (3,), hi (3,))`` of all links of body ``uid``."""
    boxes = [pb.getAABB(uid, link, physicsClientId=client)
             for link in range(-1, pb.getNumJoints(uid, physicsClientId=client))]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def body_is_open(client: int, uid: int) -> bool:
    """Whether body ``uid`` of ``client``, alone in its client, is open at its current pose (see the
    module's docstring): one vertical ray, then :data:`N_SIDES` horizontal rays."""
    lo, hi = _aabb(client, uid)
    height = float(hi[2] - lo[2])
    cx, cy = 0.5 * (lo[:2] + hi[:2])
    margin = 0.01 + 0.1 * height
    hit = pb.rayTest([cx, cy, hi[2] + margin], [cx, cy, lo[2] - margin], physicsClientId=client)[0]
    if hit[0] != uid:
        return False  # nothing under the middle: a ring or a frame holds nothing
    z_hit = float(hit[3][2])
    if hi[2] - z_hit < max(MIN_DEPTH_FRACTION * height, MIN_DEPTH):
        return False
    z = 0.5 * (z_hit + hi[2])
    reach = float(np.linalg.norm(hi[:2] - lo[:2])) + margin
    angles = 2 * math.pi * np.arange(N_SIDES) / N_SIDES
    starts = [[cx, cy, z]] * N_SIDES
    ends = [[cx + reach * math.cos(a), cy + reach * math.sin(a), z] for a in angles]
    return all(r[0] == uid for r in pb.rayTestBatch(starts, ends, physicsClientId=client))


def _probe(path: str, scale: float) -> bool:
    client = pb.connect(pb.DIRECT)
    if client < 0:
        raise RuntimeError("could not start a pybullet DIRECT client")
    try:
        for copy in (collision_only_urdf(path), visual_geometry_urdf(path)):
            try:
                uid = pb.loadURDF(copy, [0, 0, 0], [0, 0, 0, 1], useFixedBase=True, globalScaling=scale,
                                  physicsClientId=client)
            except pb.error:
                continue
            is_open = body_is_open(client, uid)
            pb.removeBody(uid, physicsClientId=client)
            if is_open:
                return True
        return False
    finally:
        pb.disconnect(physicsClientId=client)


def urdf_is_open(path: str, scale: float = 1.0) -> bool:
    """Whether the URDF file ``path`` at ``scale`` describes an open object (see the module's
    docstring). A file pybullet cannot load is not open (loading it in a world reports the error)."""
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError:
        return False
    key = (real, st.st_mtime, st.st_size, float(scale))
    if key not in _CACHE:
        _CACHE[key] = _probe(real, float(scale))
    return _CACHE[key]
