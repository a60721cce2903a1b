"""Allocentric relations isOnTop and isIn from world-frame axis-aligned bounding boxes.

Pure array functions, batched over any leading axes (one scene ``(M, 2, 3)`` or particles
``(K, M, 2, 3)``). The floor, when present, is an extra support with index ``M`` (column ``M`` of the
isOnTop matrix). Margins are symmetric: the same tolerance applies on every side of a box.

Definitions, for objects a (subject) and b (object), with AABBs ``[lo, hi]``:

* ``isIn(a, b)``: a's box lies inside b's box in x and y (within ``margin`` on each side), and a's
  bottom is between b's bottom and b's top (within ``margin``) but not above b's top minus
  ``max(rim, rim_fraction * height of b)``, and b may contain others (``hollow``: open containers
  and meshes, not solid primitives; a block perceived sunk into another is not in it).
* ``isOnTop(a, b)``: a's bottom is within ``z_margin`` of b's top, a's and b's footprints overlap by
  at least ``overlap`` in x and y, a is not in b, and a is not in a container c that is itself on b.
  ``isOnTop(a, floor)``: a's bottom is within ``z_margin`` of z = 0.

Hysteresis: a relation that holds stays true until the test fails with every margin widened by
``hysteresis``; one that does not hold needs the strict test.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RelationConfig:
    """Tolerances (metres) of the bounding-box relation tests."""

    z_margin: float = 0.015
    """isOnTop: maximum gap (or overlap) between a's bottom and b's top."""
    overlap: float = 0.005
    """isOnTop: minimum footprint overlap in x and in y."""
    margin: float = 0.01
    """isIn: tolerance on every side of the container's box."""
    rim: float = 0.005
    """isIn: a's bottom must be at least this far below b's top ..."""
    rim_fraction: float = 0.25
    """... and at least this fraction of b's height below it."""
    hysteresis: float = 0.01
    """Extra tolerance for a relation that already holds to keep holding."""

    def __post_init__(self):
        for name in ("z_margin", "overlap", "margin", "rim", "rim_fraction", "hysteresis"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"RelationConfig.{name} must be >= 0")


class _PairGeometry:
    """Continuous quantities of the bounding-box tests for all pairs, computed once and thresholded
    for the strict test, the widened (hysteresis) test and the put-down support test.

    Pairs ``(..., M, M)``: subject a on axis -2, object b on axis -1.
    """

    def __init__(self, aabbs: np.ndarray, valid: np.ndarray, floor: bool, cfg: RelationConfig,
                 hollow: np.ndarray | None = None):
        lo = aabbs[..., 0, :]
        hi = aabbs[..., 1, :]
        n = valid.shape[-1]
        self.pairs = valid[..., :, None] & valid[..., None, :] & ~np.eye(n, dtype=bool)
        # per axis, subject a as a column (..., M, 1) against object b as a row (..., 1, M)
        (ax_lo, ay_lo, az_lo), (ax_hi, ay_hi, _) = ([lo[..., d, None] for d in range(3)],
                                                       [hi[..., d, None] for d in range(3)])
        (bx_lo, by_lo, bz_lo), (bx_hi, by_hi, bz_hi) = ([lo[..., None, :, d] for d in range(3)],
                                                       [hi[..., None, :, d] for d in range(3)])
        # isIn: how far a's footprint lies inside b's (negative: sticks out), a's bottom above b's
        # bottom, and a's bottom below b's rim (a quarter of b's height, so that an object sunk a
        # few millimetres into a solid table top is not "in" it)
        self.inside_xy = np.minimum(np.minimum(ax_lo - bx_lo, bx_hi - ax_hi),
                                    np.minimum(ay_lo - by_lo, by_hi - ay_hi))
        self.above_bottom = az_lo - bz_lo
        rim = np.maximum(cfg.rim, cfg.rim_fraction * (bz_hi - bz_lo))
        self.below_rim = (bz_hi - rim) - az_lo
        # an object cannot contain one with a bigger footprint (guards against overlapping equal boxes)
        smaller = ((ax_hi - ax_lo <= bx_hi - bx_lo + 1e-9) & (ay_hi - ay_lo <= by_hi - by_lo + 1e-9))
        self.can_be_in = smaller & self.pairs
        if hollow is not None:  # a solid object contains nothing, even when perceived sunk into
            self.can_be_in &= np.asarray(hollow, dtype=bool)[None, :]
        # isOnTop: footprint overlap (the smaller of x and y) and gap between a's bottom and b's top
        self.overlap = np.minimum(np.minimum(ax_hi, bx_hi) - np.maximum(ax_lo, bx_lo),
                                  np.minimum(ay_hi, by_hi) - np.maximum(ay_lo, by_lo))
        self.gap = np.abs(az_lo - bz_hi)
        self.floor_gap = np.where(valid & np.bool_(floor), np.abs(lo[..., 2]), np.inf)

    def is_in(self, cfg: RelationConfig, widen: float) -> np.ndarray:
        m = cfg.margin + widen
        return self.can_be_in & (self.inside_xy >= -m) & (self.above_bottom >= -m) & (self.below_rim >= -widen)

    def resting_on(self, overlap: float, z_margin: float) -> np.ndarray:
        """The bounding-box isOnTop test alone ``(..., M, M + 1)``: a's bottom within ``z_margin`` of
        b's top (or of z = 0, column M) and footprints overlapping by ``overlap`` in x and y."""
        on = self.pairs & (self.overlap >= overlap) & (self.gap <= z_margin)
        return np.concatenate([on, (self.floor_gap <= z_margin)[..., None]], axis=-1)

    def masks(self, cfg: RelationConfig, widen: float) -> tuple[np.ndarray, np.ndarray]:
        is_in = self.is_in(cfg, widen)
        on_top = self.resting_on(cfg.overlap - widen, cfg.z_margin + widen)
        on_top[..., :-1] &= ~is_in
        return _not_through_containers(on_top, is_in), is_in


def _not_through_containers(on_top: np.ndarray, is_in: np.ndarray) -> np.ndarray:
    """An object in container c is not on top of what c stands on (a thin tray floor would pass the
    test): drop isOnTop(a, b) when isIn(a, c) and isOnTop(c, b) for some c."""
    if not is_in.any():
        return on_top
    through = np.matmul(is_in.astype(np.float32), on_top.astype(np.float32)) > 0
    return on_top & ~through


def _checked(aabbs, valid) -> tuple[np.ndarray, np.ndarray]:
    aabbs = np.asarray(aabbs, dtype=float)
    if aabbs.ndim < 3 or aabbs.shape[-2:] != (2, 3):
        raise ValueError(f"aabbs must have shape (..., M, 2, 3), got {aabbs.shape}")
    if valid is None:
        valid = np.ones(aabbs.shape[:-2], dtype=bool)
    return aabbs, np.broadcast_to(np.asarray(valid, dtype=bool), aabbs.shape[:-2])


def relation_masks(aabbs: np.ndarray, valid: np.ndarray | None = None, *, static: np.ndarray | None = None,
                   floor: bool = True, config: RelationConfig = RelationConfig(),
                   previous: tuple[np.ndarray, np.ndarray] | None = None,
                   hollow: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """isOnTop and isIn as boolean matrices.

    Args:
        aabbs: ``(..., M, 2, 3)`` world AABBs (metres).
        valid: ``(..., M)`` bool, objects to consider (e.g. known, not parked). Default: all.
        static: ``(M,)`` bool; static objects are never subjects (the table is on nothing).
        floor: whether the scene has a floor plane at z = 0 (support index ``M``).
        previous: the ``(on_top, is_in)`` returned at the previous update, for hysteresis.
        hollow: ``(M,)`` bool, objects that may contain others (:attr:`Scene.hollow
            <physics.scene.Scene.hollow>`); default: all.

    Returns:
        ``on_top (..., M, M + 1)`` with ``on_top[..., a, b]`` = isOnTop(a, b) (column M: the floor),
        and ``is_in (..., M, M)`` with ``is_in[..., a, b]`` = isIn(a, b).
    """
    aabbs, valid = _checked(aabbs, valid)
    return _relations(_PairGeometry(aabbs, valid, floor, config, hollow), config, static, previous)


def _relations(g: _PairGeometry, config: RelationConfig, static, previous):
    on_top, is_in = g.masks(config, 0.0)
    # the widened test matters only for relations that held and fail the strict test now
    if previous is not None and ((previous[1] & ~is_in).any() or (previous[0] & ~on_top).any()):
        on_relaxed, in_relaxed = g.masks(config, config.hysteresis)
        is_in = is_in | (previous[1] & in_relaxed)
        on_top = _not_through_containers(on_top | (previous[0] & on_relaxed), is_in)
        on_top[..., :-1] &= ~is_in
    if static is not None:
        subj = ~np.asarray(static, dtype=bool)
        on_top = on_top & subj[:, None]
        is_in = is_in & subj[:, None]
    return on_top, is_in


def supported_mask(aabbs: np.ndarray, is_in: np.ndarray, valid: np.ndarray | None = None, *,
                   static: np.ndarray | None = None, floor: bool = True, z_gap: float = 0.03,
                   config: RelationConfig = RelationConfig()) -> np.ndarray:
    """Objects ``(..., M)`` that rest on something (bottom within ``z_gap`` of a support's top, with
    overlapping footprints, or on the floor) or are in something (``is_in`` from
    :func:`relation_masks`); a looser isOnTop, computed in one pass, for deciding that a held object
    was put down."""
    aabbs, valid = _checked(aabbs, valid)
    return _supported(_PairGeometry(aabbs, valid, floor, config), is_in, static, z_gap, config)


def _supported(g: _PairGeometry, is_in, static, z_gap: float, config: RelationConfig) -> np.ndarray:
    out = g.resting_on(config.overlap, z_gap).any(axis=-1) | np.asarray(is_in).any(axis=-1)
    if static is not None:
        out &= ~np.asarray(static, dtype=bool)
    return out


def relations_and_support(aabbs: np.ndarray, valid: np.ndarray | None = None, *,
                          static: np.ndarray | None = None, floor: bool = True,
                          config: RelationConfig = RelationConfig(),
                          previous: tuple[np.ndarray, np.ndarray] | None = None,
                          z_gap: float = 0.03, hollow: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`relation_masks` and :func:`supported_mask` from one pass over the box pairs: returns
    ``(on_top (..., M, M + 1), is_in (..., M, M), supported (..., M))``."""
    aabbs, valid = _checked(aabbs, valid)
    g = _PairGeometry(aabbs, valid, floor, config, hollow)
    on_top, is_in = _relations(g, config, static, previous)
    return on_top, is_in, _supported(g, is_in, static, z_gap, config)


def relation_list(on_top: np.ndarray, is_in: np.ndarray, object_ids, p_on_top: np.ndarray | None = None,
                  p_in: np.ndarray | None = None, threshold: float = 0.0):
    """Relations as ``[{"subject", "predicate", "object", "p"}]`` for the estimate stream.

    With boolean matrices only, p is 1.0 for each true entry. With probability matrices
    ``p_on_top (M, M+1)`` / ``p_in (M, M)``, every entry with p > ``threshold`` is listed.
    """
    names = list(object_ids) + ["floor"]
    out = []
    src_on = p_on_top if p_on_top is not None else on_top.astype(float)
    src_in = p_in if p_in is not None else is_in.astype(float)
    for (a, b) in zip(*np.nonzero(src_in > threshold)):
        out.append({"subject": names[a], "predicate": "isIn", "object": names[b],
                    "p": round(float(src_in[a, b]), 4)})
    for (a, b) in zip(*np.nonzero(src_on > threshold)):
        out.append({"subject": names[a], "predicate": "isOnTop", "object": names[b],
                    "p": round(float(src_on[a, b]), 4)})
    return out
