"""Looks: viewpoints (a user's list in YAML, or sampled around the places the particles put the
object), their costs, and the probability that each finds the object in each particle, by ray tests
in the particle worlds of the filter's pool (occlusion by everything the particle believes).

Viewpoint file (YAML or JSON)::

    cost: {fixed: 1.0, per_metre: 1.0}     # optional: a look's fixed cost, and per metre of travel
    start: [1.2, 0.0, 1.3]                 # optional: where the camera is (default: the scene camera)
    viewpoints:                            # a camera each, fields as a frame's cameras
      - {id: left, position: [0.5, 1.2, 1.4], target: [0.0, 0.3, 0.6], fov_deg: 60}
    regions:                               # optional: boxes searched as regions of their own
      - {name: shelf, min: [0.5, -0.4, 0.9], max: [0.9, 0.4, 1.3]}
    replace_regions: false                 # true: only these regions (and elsewhere)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from physics.errors import InputError
from physics.fields import _Fields, read_yaml_with_lines
from physics.scene import CameraSpec, Scene, parse_camera
from physics.world import World

from .regions import Region


class ViewpointError(InputError):
    """A malformed viewpoint file."""


@dataclass(frozen=True)
class Viewpoint:
    """A camera pose a look is taken from: ``id`` and its :class:`~physics.scene.CameraSpec`."""

    id: str
    camera: CameraSpec

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.camera.position, dtype=float)


@dataclass(frozen=True)
class SearchConfig:
    """The search's settings.

    * ``fixed_cost``: cost of one look (say seconds to stop, look and decide), > 0;
    * ``travel_cost``: cost per metre the camera travels between viewpoints, >= 0;
    * ``exact_max_looks``: plans of at most this many looks are exact (subsets DP), longer greedy;
    * ``min_region_p``: regions below this probability get no look of their own;
    * ``miss_prob`` / ``visibility_threshold``: the detection model (default: the filter's);
    * ``views_per_region``, ``view_distance`` (m), ``view_elevation_deg``: sampled viewpoints, on a
      circle around each region's particles, looking at them from above at that elevation;
    * ``fov_deg``: field of view of sampled viewpoints.
    """

    fixed_cost: float = 1.0
    travel_cost: float = 1.0
    exact_max_looks: int = 8
    min_region_p: float = 0.01
    miss_prob: float | None = None
    visibility_threshold: float | None = None
    views_per_region: int = 5
    view_distance: float = 1.0
    view_elevation_deg: float = 55.0
    fov_deg: float = 60.0

    def __post_init__(self):
        if not self.fixed_cost > 0 or not self.travel_cost >= 0:
            raise ValueError("SearchConfig.fixed_cost must be > 0 and travel_cost >= 0")
        if self.exact_max_looks < 0 or self.views_per_region < 1:
            raise ValueError("SearchConfig.exact_max_looks must be >= 0 and views_per_region >= 1")
        if not 0 <= self.min_region_p < 1 or not self.view_distance > 0 or not 0 < self.view_elevation_deg <= 90:
            raise ValueError("SearchConfig: min_region_p in [0, 1), view_distance > 0, elevation in (0, 90]")
        if self.miss_prob is not None and not 0 < self.miss_prob <= 1:
            raise ValueError("SearchConfig.miss_prob must be in (0, 1]")


@dataclass(frozen=True)
class ViewpointFile:
    """A parsed viewpoint file: viewpoints, optional start, cost overrides, user regions."""

    viewpoints: tuple[Viewpoint, ...]
    start: np.ndarray | None = None
    fixed_cost: float | None = None
    travel_cost: float | None = None
    regions: tuple[Region, ...] = ()
    replace_regions: bool = False
    extra: dict = field(default_factory=dict)


def read_viewpoints(path: str) -> ViewpointFile:
    """Read and validate a viewpoint file; raises :class:`ViewpointError` naming file, line, field."""
    data, lines = read_yaml_with_lines(path, "viewpoint file", ViewpointError)
    f = _Fields(str(path), lines, ViewpointError)
    data = f.mapping(data, "")
    f.only(data, {"viewpoints", "start", "cost", "regions", "replace_regions"}, "")
    raw = data.get("viewpoints", [])
    if not isinstance(raw, list):
        raise f.error("viewpoints", f"must be a list of cameras, got {type(raw).__name__}")
    views, seen = [], set()
    for i, c in enumerate(raw):
        spec = parse_camera(f, c, f"viewpoints[{i}]", extra={"id"}, orientation=True)
        vid = c.get("id", f"view{i}")
        if not isinstance(vid, str) or not vid or vid in seen:
            raise f.error(f"viewpoints[{i}].id", f"must be a unique non-empty string, got {vid!r}")
        seen.add(vid)
        views.append(Viewpoint(vid, spec))
    start = None if data.get("start") is None else np.array(f.vector(data["start"], "start", 3))
    fixed = travel = None
    if data.get("cost") is not None:
        cost = f.mapping(data["cost"], "cost")
        f.only(cost, {"fixed", "per_metre"}, "cost")
        if "fixed" in cost:
            fixed = f.number(cost["fixed"], "cost.fixed", positive=True)
        if "per_metre" in cost:
            travel = f.number(cost["per_metre"], "cost.per_metre", nonneg=True)
    regions = []
    raw_regions = data.get("regions", [])
    if not isinstance(raw_regions, list):
        raise f.error("regions", "must be a list of {name, min, max} boxes")
    for i, r in enumerate(raw_regions):
        where = f"regions[{i}]"
        r = f.mapping(r, where)
        f.only(r, {"name", "min", "max"}, where)
        f.require(r, ("name", "min", "max"), where)
        if not isinstance(r["name"], str) or not r["name"]:
            raise f.error(f"{where}.name", f"must be a non-empty string, got {r['name']!r}")
        lo, hi = f.vector(r["min"], f"{where}.min", 3), f.vector(r["max"], f"{where}.max", 3)
        if not all(a < b for a, b in zip(lo, hi)):
            raise f.error(f"{where}.max", "must be greater than min on every axis")
        regions.append(Region(r["name"], "box", box=(lo, hi)))
    replace = data.get("replace_regions", False)
    if not isinstance(replace, bool):
        raise f.error("replace_regions", f"must be true or false, got {replace!r}")
    return ViewpointFile(tuple(views), start, fixed, travel, tuple(regions), replace)


def static_boxes(scene: Scene) -> np.ndarray:
    """World AABBs ``(M, 2, 3)`` of the scene's objects at their given poses (static objects at
    their fixed ones), read in a scratch world."""
    w = World(scene)
    try:
        return w.aabbs()
    finally:
        w.close()


def sample_viewpoints(centres: list[tuple[str, np.ndarray]], config: SearchConfig,
                      rng: np.random.Generator) -> list[Viewpoint]:
    """``config.views_per_region`` viewpoints around each ``(name, centre (3,))``: on a circle of
    radius ``view_distance cos(elevation)`` at height ``view_distance sin(elevation)`` above the
    centre, evenly spaced from a random starting angle, looking at the centre."""
    out = []
    el = math.radians(config.view_elevation_deg)
    for name, c in centres:
        phase = rng.uniform(0.0, 2.0 * math.pi)
        for j in range(config.views_per_region):
            a = phase + 2.0 * math.pi * j / config.views_per_region
            pos = np.asarray(c, float) + config.view_distance * np.array(
                [math.cos(el) * math.cos(a), math.cos(el) * math.sin(a), math.sin(el)])
            pos[2] = max(pos[2], 0.2)
            spec = CameraSpec(position=tuple(float(v) for v in pos), target=tuple(float(v) for v in c),
                              fov_deg=config.fov_deg)
            out.append(Viewpoint(f"{name} #{j + 1}", spec))
    return out


def detection(pool, ps, obj: int, known: np.ndarray, views: list[Viewpoint], miss_prob: float,
              threshold: float) -> np.ndarray:
    """``(V, K)``: the probability that a look from each viewpoint finds object ``obj`` if particle
    k is the truth: ``1 - miss_prob`` where the particle's ray tests (its world holding the known
    objects ``known (M,)`` at the particle's poses) see at least ``threshold`` of the object's sample
    points, else 0."""
    if not views:
        return np.zeros((0, len(ps.weights)))
    seen = pool.look(ps.poses, np.flatnonzero(known), np.array([obj]), tuple(v.camera for v in views), threshold)
    return np.where(seen[..., 0], 1.0 - miss_prob, 0.0)


def travel_costs(start: np.ndarray, views: list[Viewpoint], fixed: float, per_metre: float) -> np.ndarray:
    """``(L + 1, L)``: cost of a look from each viewpoint after each viewpoint (rows ``0..L-1``) or
    from ``start (3,)`` (row L): ``fixed + per_metre * distance``."""
    pts = np.array([v.position for v in views] + [np.asarray(start, float)]).reshape(-1, 3)
    L = len(views)
    dist = np.linalg.norm(pts[:, None, :] - pts[None, :L, :], axis=-1)
    return fixed + per_metre * dist
