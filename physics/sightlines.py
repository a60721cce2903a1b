"""The sight lines from cameras to sample points of objects in copies of a scene, and what decides
whether each is clear (the point is seen): box tests where they can say it as a ray test would, ray
tests otherwise (pybullet's, batched per client). :func:`~physics.visibility.seen_points` uses them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rays import ray_cast
from .transforms import quat_rotate
from .world import World

RAY_BEYOND = 1.05
"""A sightline's ray goes from the camera to this many times its sample point's distance: a little
beyond the point, so that the object is hit (:meth:`Sightlines.cast`)."""

BOX_PAD = 1e-3
"""How much wider (m, on every side) the boxes are that the box tests of :class:`Sightlines` meet a
segment with: rounding."""

SOLID_DEPTH = 0.005
"""How far inside a box-shaped object (m) its :func:`~physics.visibility.solid_box` lies: a ray
through it surely meets the object (pybullet's ray test reports a hit for it) and no margin or
rounding can say otherwise."""


@dataclass(frozen=True)
class Solids:
    """Boxes that lie inside objects (:func:`~physics.visibility.solid_box`), posed in G worlds:
    objects ``index (S,)``, their boxes' ``centre (S, 3)`` and ``half (S, 3)`` extents in the
    object's frame (m), and the objects' link-frame ``poses (G, S, 7)`` in each world (scene
    frame)."""

    index: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    poses: np.ndarray

    @classmethod
    def posed(cls, boxes: dict[int, tuple[np.ndarray, np.ndarray]], poses: np.ndarray) -> "Solids":
        """The solid ``boxes`` (object index -> :func:`~physics.visibility.solid_box`) of the objects
        at ``poses (G, M, 7)``."""
        index = np.array(sorted(boxes), dtype=int)
        centre = np.array([boxes[i][0] for i in index]).reshape(-1, 3)
        half = np.array([boxes[i][1] for i in index]).reshape(-1, 3)
        return cls(index, centre, half, np.asarray(poses, dtype=float)[:, index])


def segment_spans(starts: np.ndarray, ends: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each segment ``starts -> ends (N, 3)`` enters and leaves each of its own B boxes ``lo,
    hi (N, B, 3)`` (the slab test, boxes closed), as fractions of its length: ``enter, leave (N,
    B)``, the segment meeting the box where ``enter <= leave``."""
    d = (ends - starts)[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (lo - starts[:, None, :]) * inv
        t1 = (hi - starts[:, None, :]) * inv
    tmin, tmax = np.minimum(t0, t1), np.maximum(t0, t1)
    parallel = d == 0.0  # parallel to a slab: inside it or never
    if parallel.any():
        inside = (starts[:, None, :] >= lo) & (starts[:, None, :] <= hi)
        tmin = np.where(parallel, np.where(inside, -np.inf, np.inf), tmin)
        tmax = np.where(parallel, np.where(inside, np.inf, -np.inf), tmax)
    enter = np.maximum(np.maximum(tmin[..., 0], tmin[..., 1]), np.maximum(tmin[..., 2], 0.0))
    return enter, np.minimum(np.minimum(tmax[..., 0], tmax[..., 1]), np.minimum(tmax[..., 2], 1.0))


class Sightlines:
    """The rays from V cameras at ``positions (V, 3)`` (scene frame) to the sample points ``pts (G,
    n, P, 3)`` of objects ``indices`` in G worlds, with what is known of the worlds' bodies
    (``boxes``, ``convex``, ``solids``: see :func:`~physics.visibility.seen_points`); the methods
    take and return bool ``(V, G, n, P)`` masks of rays."""

    def __init__(self, worlds: list[World], indices: list[int], positions: np.ndarray, pts: np.ndarray,
                 boxes: np.ndarray | None = None, convex: np.ndarray | None = None, solids: Solids | None = None):
        self.indices, self.positions, self.pts = np.asarray(indices), positions, pts
        self.boxes, self.convex = boxes, convex
        self.solids = solids if boxes is not None and solids is not None and len(solids.index) else None
        self.origins = np.array([w.origin for w in worlds])  # (G, 3)
        self.clients = np.array([w.client for w in worlds])  # (G,)
        self.uids = np.array([[w.uids[i] for i in indices] for w in worlds])  # (G, n)

    def clear(self, sel: np.ndarray) -> np.ndarray:
        """The rays of ``sel`` to a point of a convex object above the floor, from a camera above
        the floor, whose segment misses every other box: seen (none without ``boxes`` and
        ``convex``)."""
        out = np.zeros(sel.shape, dtype=bool)
        if self.boxes is None or self.convex is None or not sel.any():
            return out
        v_idx, g_idx, o_idx, p_idx = np.nonzero(sel)
        p_sel = self.pts[g_idx, o_idx, p_idx]
        cam = self.positions[v_idx]
        lo, hi = self.boxes[:, :, 0] - BOX_PAD, self.boxes[:, :, 1] + BOX_PAD
        enter, leave = segment_spans(cam, p_sel, lo[g_idx], hi[g_idx])
        meets = enter <= leave  # (N, B)
        meets[np.arange(len(o_idx)), self.indices[o_idx]] = False  # the object does not hide itself
        ok = ~meets.any(axis=1) & np.asarray(self.convex, dtype=bool)[o_idx] & (p_sel[:, 2] > 0) & (cam[:, 2] > 0)
        out[v_idx[ok], g_idx[ok], o_idx[ok], p_idx[ok]] = True
        return out

    def reached(self, sel: np.ndarray) -> np.ndarray:
        """``(G, B)`` bool: the boxes (1 mm wider) that the segments of the rays of ``sel`` meet
        (:meth:`cast`'s segments, a little beyond the point: every ray it casts for them is part of
        one), the rays' own objects' included: the only bodies those ray tests can hit (no column
        without ``boxes``)."""
        if self.boxes is None:
            return np.zeros((len(self.origins), 0), dtype=bool)
        out = np.zeros(self.boxes.shape[:2], dtype=bool)
        if not sel.any():
            return out
        v_idx, g_idx, o_idx, p_idx = np.nonzero(sel)
        cam, end = self._ends(v_idx, g_idx, o_idx, p_idx)
        lo, hi = self.boxes[:, :, 0] - BOX_PAD, self.boxes[:, :, 1] + BOX_PAD
        enter, leave = segment_spans(cam, end, lo[g_idx], hi[g_idx])
        np.logical_or.at(out, g_idx, enter <= leave)
        return out

    def hidden_by_solids(self, sel: np.ndarray) -> np.ndarray:
        """The rays of ``sel`` that go through a solid box of another object (from outside it)
        before they enter their own object's box: hidden (none without ``solids``)."""
        solids = self.solids
        if solids is None or not sel.any():
            return np.zeros(sel.shape, dtype=bool)
        centre, axes, cam_local, outside = self._solid_frames(solids)
        v_idx, g_idx, o_idx, p_idx = np.nonzero(sel)
        _, end, own_enter = self._own_entry(v_idx, g_idx, o_idx, p_idx)
        d = end[:, None, :] - centre[g_idx]  # (N, S, 3)
        ax = axes[g_idx]  # (N, S, 3, 3)
        end_local = d[..., None, 0] * ax[..., 0] + d[..., None, 1] * ax[..., 1] + d[..., None, 2] * ax[..., 2]
        S = len(solids.index)
        half = np.broadcast_to(solids.half, end_local.shape).reshape(-1, 1, 3)
        enter, leave = (t.reshape(-1, S) for t in segment_spans(cam_local[v_idx, g_idx].reshape(-1, 3),
                                                                 end_local.reshape(-1, 3), -half, half))
        other = solids.index[None, :] != self.indices[o_idx][:, None]
        hides = np.any((enter <= leave) & (enter < own_enter[:, None]) & outside[v_idx, g_idx] & other, axis=1)
        out = np.zeros(sel.shape, dtype=bool)
        out[v_idx[hides], g_idx[hides], o_idx[hides], p_idx[hides]] = True
        return out

    def _solid_frames(self, solids: Solids) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The solids' centres ``(G, S, 3)`` and axes ``(G, S, 3, 3)`` (row i: local axis i) in each
        world, the cameras in their frames ``(V, G, S, 3)`` and whether they are well outside them
        ``(V, G, S)`` (a ray from inside a body may not report it)."""
        q = solids.poses[..., 3:]
        shape = solids.poses[..., :3].shape
        centre = solids.poses[..., :3] + quat_rotate(q, np.broadcast_to(solids.centre, shape))
        axes = np.stack([quat_rotate(q, np.broadcast_to(e, shape)) for e in np.eye(3)], axis=-2)
        d = self.positions[:, None, None, :] - centre[None]
        cam_local = (d[..., None, :] * axes[None]).sum(axis=-1)
        outside = np.any(np.abs(cam_local) > solids.half + SOLID_DEPTH + 0.01, axis=-1)
        return centre, axes, cam_local, outside

    def _ends(self, v_idx, g_idx, o_idx, p_idx) -> tuple[np.ndarray, np.ndarray]:
        """Camera and end ``(N, 3)`` (scene frame) of the rays, a little beyond their points."""
        cam = self.positions[v_idx]
        return cam, cam + (self.pts[g_idx, o_idx, p_idx] - cam) * RAY_BEYOND

    def _own_entry(self, v_idx, g_idx, o_idx, p_idx) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera and end ``(N, 3)`` (scene frame) of the rays, and where they enter their object's
        box, 1 mm wider, as a fraction of their length ``(N,)``."""
        cam, end = self._ends(v_idx, g_idx, o_idx, p_idx)
        own = self.boxes[g_idx, self.indices[o_idx]][:, None]  # (N, 1, 2, 3)
        return cam, end, segment_spans(cam, end, own[..., 0, :] - BOX_PAD, own[..., 1, :] + BOX_PAD)[0][:, 0]

    def hidden_before_box(self, sel: np.ndarray) -> np.ndarray:
        """The rays of ``sel`` that hit another body before they enter their object's box, 1 mm
        wider (short ray tests, as far as there): hidden (none without ``boxes``)."""
        out = np.zeros(sel.shape, dtype=bool)
        if self.boxes is None or not sel.any():
            return out
        v_idx, g_idx, o_idx, p_idx = np.nonzero(sel)
        start, end = self._segments(v_idx, g_idx, o_idx, p_idx)
        enter = self._own_entry(v_idx, g_idx, o_idx, p_idx)[2]
        s = np.flatnonzero(enter > 0)
        hit = self._first_hits(g_idx[s], start[s], start[s] + (end[s] - start[s]) * enter[s, None])
        r = s[(hit >= 0) & (hit != self.uids[g_idx[s], o_idx[s]])]
        out[v_idx[r], g_idx[r], o_idx[r], p_idx[r]] = True
        return out

    def cast(self, sel: np.ndarray) -> np.ndarray:
        """The rays of ``sel`` whose first hit is their own object (seen), by ray tests a little
        beyond the point, after the short ones of :meth:`hidden_before_box` (a fraction of the
        cost) for those they do not hide."""
        sel = sel & ~self.hidden_before_box(sel)
        out = np.zeros(sel.shape, dtype=bool)
        if sel.any():
            v_idx, g_idx, o_idx, p_idx = np.nonzero(sel)
            start, end = self._segments(v_idx, g_idx, o_idx, p_idx)
            out[v_idx, g_idx, o_idx, p_idx] = self._first_hits(g_idx, start, end) == self.uids[g_idx, o_idx]
        return out

    def _segments(self, v_idx, g_idx, o_idx, p_idx) -> tuple[np.ndarray, np.ndarray]:
        """Starts and ends ``(N, 3)`` in the clients' frames of the rays, a little beyond the point
        (the object is hit)."""
        cam = self.positions[v_idx]
        start = cam + self.origins[g_idx]
        return start, start + (self.pts[g_idx, o_idx, p_idx] - cam) * RAY_BEYOND

    def _first_hits(self, g_idx: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Body id ``(N,)`` first hit by each ray ``start -> end (N, 3)`` of world ``g_idx (N,)``
        (-1: none); one batched ray test per client."""
        hit = np.empty(len(start), dtype=np.int64)
        clients = self.clients[g_idx]
        for c in np.unique(clients).tolist():
            rows = np.flatnonzero(clients == c)
            hit[rows] = ray_cast(c, start[rows], end[rows])[0]
        return hit
