"""Search regions: the places a lost object can be, derived from the scene, and which one each
particle puts it in.

Derived regions (:func:`derive_regions`): the top of each support surface (static objects, and
dynamic solids that something may rest on), the inside of each hollow object, cells of the floor
around the table (the largest static object: under it, behind it, in front of it, left and right of
it, "behind" being the side away from the robot's camera), and "held by H" for each tracked hand
(or "held" when no hand is tracked). A user's regions (axis-aligned boxes, :class:`Region` with a
``box``) come first: a particle whose object lies in one of them is in it, whatever its support.

Every particle falls in exactly one region or in "elsewhere" (unsupported, not held, in no box), by
the support labels of the filter (:func:`estimator.belief.support_labels`: held, in, on top).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.modes import is_held
from physics.scene import Scene

from ...belief import support_labels
from ...resampling import normalise_log_weights

ELSEWHERE = "elsewhere"


@dataclass(frozen=True)
class Region:
    """A place to search. ``kind``: ``"box"`` (a user's axis-aligned box ``box = (min (3,), max
    (3,))``), ``"on"`` / ``"in"`` (on top of / inside object ``support``), ``"floor"`` (the floor
    cell ``cell``: ``"under"``, ``"behind"``, ``"front"``, ``"left"``, ``"right"`` of the table, or
    ``"all"``), ``"held"`` (by tracked hand ``hand``; None: by anyone)."""

    name: str
    kind: str
    support: str | None = None
    cell: str | None = None
    hand: str | None = None
    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None

    def __post_init__(self):
        if self.kind not in ("box", "on", "in", "floor", "held"):
            raise ValueError(f"Region.kind must be box, on, in, floor or held, got {self.kind!r}")
        if self.kind == "box" and (self.box is None or not np.all(np.less(self.box[0], self.box[1]))):
            raise ValueError(f"Region {self.name!r}: a box region needs box = (min, max) with min < max")


@dataclass(frozen=True)
class ParticleSet:
    """What the search reads of a belief: ``poses (K, M, 7)``, normalised ``weights (K,)``,
    ``modes (K, M)``, ``on_top (K, M, M+1)``, ``is_in (K, M, M)``, the ``object_ids`` (M), the
    tracked hand each object was last seen with ``hold_hand`` (M, None: none) and the tracked hands'
    positions ``hands`` (name -> (3,))."""

    poses: np.ndarray
    weights: np.ndarray
    modes: np.ndarray
    on_top: np.ndarray
    is_in: np.ndarray
    object_ids: tuple[str, ...]
    hold_hand: tuple[str | None, ...] = ()
    hands: dict | None = None

    @classmethod
    def from_estimator(cls, est, hands: dict | None = None) -> "ParticleSet":
        """The particles of a :class:`~estimator.filter.SceneEstimator` as they are now (after its
        last update, resampled or not); ``hands``: the tracked hands of the last frame (name ->
        ``(3,)``; the hands the objects were last seen with are added)."""
        s = est.state
        w, _ = normalise_log_weights(s.log_weights)
        hands = {k: np.asarray(v, float) for k, v in (hands or {}).items()}
        for h in est.memory.hold_hand:
            if h is not None and h not in hands:
                hands[h] = None
        return cls(s.poses.copy(), w, s.modes.copy(), s.on_top.copy(), s.is_in.copy(), tuple(est.object_ids),
                   tuple(est.memory.hold_hand), hands)


def table_of(scene: Scene, boxes: np.ndarray) -> int | None:
    """Index of the table: the static object (not the floor) with the largest footprint, from world
    AABBs ``boxes (M, 2, 3)``; None when the scene has no static object."""
    static = [i for i, o in enumerate(scene.objects) if o.static]
    if not static:
        return None
    area = [np.prod(boxes[i, 1, :2] - boxes[i, 0, :2]) for i in static]
    return static[int(np.argmax(area))]


def derive_regions(scene: Scene, boxes: np.ndarray, hands=(), camera_xy: np.ndarray | None = None) -> list[Region]:
    """The regions of a scene (see the module's docstring): ``boxes (M, 2, 3)`` world AABBs of the
    objects (static ones at their fixed poses), ``hands`` the tracked hands' names, ``camera_xy
    (2,)`` where the robot looks from (for "behind"; default: the scene camera, else +x)."""
    out: list[Region] = []
    for i, o in enumerate(scene.objects):
        if o.may_contain:
            out.append(Region(f"inside {o.id}", "in", support=o.id))
    for i, o in enumerate(scene.objects):
        if not o.may_contain:
            out.append(Region(f"on {o.id}", "on", support=o.id))
    if scene.floor:
        if table_of(scene, boxes) is None:
            out.append(Region("floor", "floor", cell="all"))
        else:
            name = scene.objects[table_of(scene, boxes)].id
            for cell, words in (("under", "under"), ("behind", "behind"), ("front", "in front of"),
                                ("left", "left of"), ("right", "right of")):
                out.append(Region(f"floor, {words} the {name}", "floor", cell=cell))
    for h in hands:
        out.append(Region(f"held by {h}", "held", hand=h))
    out.append(Region("held" if hands else "held by a person", "held"))
    return out


def floor_cells(positions: np.ndarray, table_box: np.ndarray, camera_xy: np.ndarray) -> np.ndarray:
    """Floor cell names ``(K,)`` of positions ``(K, 3)`` around a table with AABB ``(2, 3)`` seen from
    ``camera_xy (2,)``: "under" within its footprint, else "behind" / "front" / "left" / "right" by
    the direction from its centre (sectors of 90 degrees about the line of sight)."""
    lo, hi = table_box[0, :2], table_box[1, :2]
    centre = 0.5 * (lo + hi)
    sight = centre - np.asarray(camera_xy, float)[:2]
    n = np.linalg.norm(sight)
    sight = sight / n if n > 1e-9 else np.array([-1.0, 0.0])
    left_dir = np.array([-sight[1], sight[0]])
    rel = positions[:, :2] - centre
    a, b = rel @ sight, rel @ left_dir
    under = np.all((positions[:, :2] >= lo) & (positions[:, :2] <= hi), axis=1)
    cell = np.where(np.abs(a) >= np.abs(b), np.where(a >= 0, "behind", "front"), np.where(b >= 0, "left", "right"))
    return np.where(under, "under", cell)


def assign(ps: ParticleSet, obj: int, regions: list[Region], table_box: np.ndarray | None,
           camera_xy: np.ndarray, floor: bool = True) -> np.ndarray:
    """Region index ``(K,)`` of object ``obj`` in each particle (``len(regions)``: elsewhere).
    Boxes first (in their order), then held (by the hand the object was last seen with, if it has
    a region, else the generic held region), inside, on top, the floor's cells."""
    K, M = ps.modes.shape
    R = len(regions)
    pos = ps.poses[:, obj, :3]
    out = np.full(K, R, dtype=int)
    todo = np.ones(K, dtype=bool)
    for r, reg in enumerate(regions):
        if reg.kind == "box":
            inside = todo & np.all((pos >= reg.box[0]) & (pos <= reg.box[1]), axis=1)
            out[inside], todo[inside] = r, False
    labels = support_labels(ps.modes, ps.on_top, ps.is_in)[:, obj]
    ids = list(ps.object_ids)
    index = {(reg.kind, reg.support, reg.cell, reg.hand): r for r, reg in enumerate(regions)}
    hand = ps.hold_hand[obj] if ps.hold_hand else None
    held_r = index.get(("held", None, None, hand), index.get(("held", None, None, None)))
    cells = floor_cells(pos, table_box, camera_xy) if table_box is not None else np.full(K, "all")
    for k in np.flatnonzero(todo):
        lab = int(labels[k])
        if lab == 0:
            r = held_r
        elif lab <= M:
            r = index.get(("in", ids[lab - 1], None, None))
        elif lab <= 2 * M:
            r = index.get(("on", ids[lab - 1 - M], None, None))
        elif lab == 2 * M + 1 and floor:
            r = index.get(("floor", None, str(cells[k]), None))
        else:
            r = None
        out[k] = R if r is None else r
    return out


def region_probabilities(labels: np.ndarray, weights: np.ndarray, n_regions: int) -> np.ndarray:
    """``(n_regions + 1,)``: the weight of the particles in each region, and elsewhere last (sums to
    1 for normalised weights)."""
    return np.bincount(labels, weights=weights, minlength=n_regions + 1)[:n_regions + 1]


def held_mask(ps: ParticleSet, obj: int) -> np.ndarray:
    """Particles ``(K,)`` in which object ``obj`` is held."""
    return is_held(ps.modes[:, obj])
