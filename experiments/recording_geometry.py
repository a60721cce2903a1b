"""Geometry for the rerun recordings (:mod:`experiments.recording`): objects' link-frame bounding
boxes and where they are, covariance ellipsoids, and the drawing of a scene's static objects (URDF
visual meshes read back from pybullet, primitives from the scene file). Units: metres; quaternions
x, y, z, w."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb
import rerun as rr
from rerun.components import FillMode
from scipy.spatial.transform import Rotation

from physics.scene import ObjectSpec, Scene
from physics.transforms import pose_compose, quat_rotate
from physics.world import World

SCENE_GREY = (205, 205, 205, 255)
_GEOM_SPHERE, _GEOM_BOX, _GEOM_CYLINDER, _GEOM_MESH = pb.GEOM_SPHERE, pb.GEOM_BOX, pb.GEOM_CYLINDER, pb.GEOM_MESH


@dataclass(frozen=True)
class LocalBox:
    """An object's bounding box in its own link frame: ``center (3,)`` and ``half_size (3,)`` (m)."""

    center: np.ndarray
    half_size: np.ndarray


def local_boxes(world: World) -> dict[str, LocalBox]:
    """Link-frame bounding box of every object of ``world`` (placed at the identity pose to measure
    it; the world's poses are changed). Units: metres."""
    poses = np.zeros((world.num_objects, 7))
    poses[:, 6] = 1.0
    world.set_poses(poses)
    boxes = world.aabbs()
    return {oid: LocalBox(0.5 * (b[0] + b[1]), 0.5 * (b[1] - b[0])) for oid, b in zip(world.object_ids, boxes)}


def boxes_at(boxes: list[LocalBox], positions: np.ndarray, orientations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World centres ``(n, 3)`` and half sizes ``(n, 3)`` of local ``boxes`` placed at link-frame
    ``positions (n, 3)`` / ``orientations (n, 4)`` x,y,z,w."""
    if not boxes:
        return np.zeros((0, 3)), np.zeros((0, 3))
    offsets = np.array([b.center for b in boxes])
    centers = np.asarray(positions, float) + quat_rotate(np.asarray(orientations, float), offsets)
    return centers, np.array([b.half_size for b in boxes])


def covariance_ellipsoids(cov: np.ndarray, sigma: float, floor: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Half axes ``(n, 3)`` (m, ``sigma`` standard deviations, at least ``floor``) and orientation
    quaternions ``(n, 4)`` x,y,z,w of the ellipsoids of position covariances ``(n, 3, 3)`` (m^2)."""
    cov = np.asarray(cov, float).reshape(-1, 3, 3)
    if not len(cov):
        return np.zeros((0, 3)), np.zeros((0, 4))
    vals, vecs = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    flip = np.linalg.det(vecs) < 0
    vecs[flip, :, 0] *= -1.0
    half = np.maximum(sigma * np.sqrt(np.clip(vals, 0.0, None)), floor)
    return half, Rotation.from_matrix(vecs).as_quat()


def static_geometry(world: World, scene: Scene) -> list[tuple[str, object]]:
    """(object id, archetype) drawing each static object at its scene pose: URDF visual meshes (or
    their primitives) read back from pybullet, primitives from the scene file."""
    out = []
    poses = world.get_poses()
    for i, spec in enumerate(scene.objects):
        if not spec.static:
            continue
        if spec.shape == "urdf":
            mesh = _urdf_visual_mesh(world, i)
            if mesh is not None:
                out.append((spec.id, mesh))
                continue
        out.append((spec.id, _primitive(spec, poses[i])))
    return out


def _primitive(spec: ObjectSpec, pose: np.ndarray):
    p, q = pose[:3], pose[3:]
    color = [tuple(int(255 * c) for c in spec.color)] if spec.color is not None else [SCENE_GREY]
    if spec.shape == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[spec.radius] * 3], centers=[p], colors=color, fill_mode=FillMode.Solid)
    if spec.shape == "cylinder":
        return rr.Cylinders3D(lengths=[spec.height], radii=[spec.radius], centers=[p], quaternions=[q],
                              colors=color, fill_mode=FillMode.Solid)
    if spec.shape == "container":
        sx, sy, sz = (0.5 * v for v in spec.size)
        w = 0.5 * spec.wall
        local_c = np.array([[0, 0, -sz + w], [sx - w, 0, 0], [-sx + w, 0, 0], [0, sy - w, 0], [0, -sy + w, 0]])
        half = np.array([[sx, sy, w], [w, sy, sz], [w, sy, sz], [sx, w, sz], [sx, w, sz]])
        centers = p + quat_rotate(np.broadcast_to(q, (5, 4)), local_c)
        return rr.Boxes3D(half_sizes=half, centers=centers, quaternions=[q] * 5, colors=color, fill_mode=FillMode.Solid)
    if spec.shape == "box":
        return rr.Boxes3D(half_sizes=[[0.5 * v for v in spec.size]], centers=[p], quaternions=[q], colors=color,
                          fill_mode=FillMode.Solid)
    raise ValueError(f"no drawing for shape {spec.shape!r}")


def _urdf_visual_mesh(world: World, index: int):
    """One :class:`rerun.Mesh3D` with every visual shape of a URDF object in world coordinates, or
    ``None`` when it has none that can be read (then its bounding box is drawn instead)."""
    import trimesh

    c = world.client
    uid = world.uids[index]
    parts, colors = [], []
    for v in pb.getVisualShapeData(uid, physicsClientId=c):
        link, geom, dims, fname, lpos, lorn, rgba = v[1], v[2], v[3], v[4], v[5], v[6], v[7]
        if geom == _GEOM_MESH:
            try:
                m = trimesh.load(fname.decode() if isinstance(fname, bytes) else fname, force="mesh")
            except (OSError, ValueError):
                continue
            m = m.copy()
            m.apply_scale(dims)
        elif geom == _GEOM_BOX:
            m = trimesh.creation.box(extents=dims)
        elif geom == _GEOM_SPHERE:
            m = trimesh.creation.icosphere(subdivisions=2, radius=dims[0])
        elif geom == _GEOM_CYLINDER:
            m = trimesh.creation.cylinder(radius=dims[1], height=dims[0])
        else:
            continue
        if link < 0:  # pybullet reports visual frames relative to the centre-of-mass frame
            wpos, worn = pb.getBasePositionAndOrientation(uid, physicsClientId=c)
        else:
            state = pb.getLinkState(uid, link, physicsClientId=c)
            wpos, worn = state[0], state[1]
        placed = pose_compose(np.array([*wpos, *worn]), np.array([*lpos, *lorn]))
        ppos, porn = placed[:3], placed[3:]
        rot = np.broadcast_to(porn, (len(m.vertices), 4))
        verts = np.asarray(ppos) + quat_rotate(rot, m.vertices)
        parts.append((verts, np.asarray(m.faces), quat_rotate(rot, m.vertex_normals)))
        colors.append(np.broadcast_to((np.asarray(rgba) * 255).astype(np.uint8), (len(verts), 4)))
    if not parts:
        return None
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    verts = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[1] + o for p, o in zip(parts, offsets)])
    return rr.Mesh3D(vertex_positions=verts, triangle_indices=faces,
                     vertex_normals=np.concatenate([p[2] for p in parts]), vertex_colors=np.concatenate(colors))
