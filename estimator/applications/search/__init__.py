"""Hidden-object search: where to look first for an object the camera has lost, from the particle
belief, and the closed loop that feeds every failed look back to the filter.

:func:`plan_search` ranks the search regions (:mod:`.regions`) by the weight of the particles in
each, chooses one viewpoint per likely region (the candidate with the largest probability of
finding the object there per unit of cost from the camera's place; candidates from the user's list
or sampled around the particles, :mod:`.looks`), and orders the looks to minimise the expected cost
of finding the object, with Bayes' rule after every failed look, at the particle level
(:mod:`.plan`: exact over all orders up to :data:`~.plan.EXACT_MAX_LOOKS` looks, greedy beyond).
Detection probabilities are per particle, from ray tests in that particle's world.

:class:`ClosedLoopSearch` runs the loop: after a failed look, the estimator gets a frame taken by
that look's camera without the object (and with whatever was seen on the way), so that physics and
negative evidence re-weight the particles; the plan is then recomputed from the new belief. The
open-loop alternative updates only the particle weights by Bayes' rule
(:meth:`SearchPlan.after_miss`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from actions.modes import is_held

from ...model.likelihood import hidden_by_person
from ...observations import Detection, Frame
from .looks import (
    SearchConfig,
    Viewpoint,
    ViewpointError,
    ViewpointFile,
    detection,
    read_viewpoints,
    sample_viewpoints,
    travel_costs,
)
from .plan import bayes_after_miss, find_probabilities, plan_order
from .regions import ELSEWHERE, ParticleSet, Region, assign, derive_regions, region_probabilities, table_of

__all__ = ["ClosedLoopSearch", "ParticleSet", "PlannedLook", "Region", "SearchConfig", "SearchPlan", "Viewpoint",
           "ViewpointError", "ViewpointFile", "look_at_point", "plan_search", "read_viewpoints"]


MIN_DETECTION = 1e-6
"""A region gets a look only if some viewpoint finds the object there with at least this probability
(a look that cannot find it would only be placed where it shortens the camera's path)."""

DEFAULT_REFERENCE = (10.0, 0.0, 0.0)
"""Where the robot is taken to look from when neither a camera nor a start is known (m)."""


@dataclass(frozen=True)
class PlannedLook:
    """One look of a plan: its ``viewpoint``, the ``regions`` it was chosen for, ``p_find`` (the
    probability that it finds the object if the looks before it failed), ``p_first`` (that it is the
    look that finds it) and ``cost`` (fixed cost plus travel from the previous viewpoint)."""

    viewpoint: Viewpoint
    regions: tuple[str, ...]
    p_find: float
    p_first: float
    cost: float

    def to_json(self) -> dict:
        c = self.viewpoint.camera
        return {"viewpoint": self.viewpoint.id, "position": [round(float(v), 4) for v in c.position],
                "target": [round(float(v), 4) for v in c.target], "regions": list(self.regions),
                "p_find": round(self.p_find, 4), "p_first": round(self.p_first, 4), "cost": round(self.cost, 4)}


@dataclass(frozen=True)
class SearchPlan:
    """A search plan for ``object_id`` at time ``t``: ``regions`` (name, probability) ranked, with
    ``elsewhere`` last; ``looks`` in order; ``expected_cost`` of finding the object (looks after it
    is found are not paid; if every look fails, all are); ``p_found`` by the whole plan; ``method``
    ``"exact"`` or ``"greedy"``. Kept for Bayes' rule: ``weights (K,)``, region index per particle
    ``labels (K,)`` (``len(region_names)``: elsewhere), ``region_names``, the detection
    probabilities of the planned looks ``d (L, K)``; ``candidates``: the viewpoints the plan chose
    from (the user's, or those sampled around the likely regions)."""

    object_id: str
    t: float | None
    regions: list[tuple[str, float]]
    looks: list[PlannedLook]
    expected_cost: float
    p_found: float
    method: str
    weights: np.ndarray
    labels: np.ndarray
    region_names: tuple[str, ...]
    d: np.ndarray
    candidates: int = 0

    def to_json(self) -> dict:
        return {"object": self.object_id, "t": self.t,
                "regions": [{"region": n, "p": round(float(p), 4)} for n, p in self.regions],
                "plan": [lk.to_json() for lk in self.looks], "expected_cost": round(self.expected_cost, 4),
                "p_found": round(self.p_found, 4), "method": self.method, "candidates": self.candidates}

    def region_p(self, name: str) -> float:
        return dict(self.regions).get(name, 0.0)

    def after_miss(self, i: int = 0) -> tuple[dict[str, float], np.ndarray]:
        """Open loop: the region probabilities (name -> p, elsewhere included) and particle weights
        ``(K,)`` after look ``i`` of the plan failed, by Bayes' rule on the particles."""
        w = bayes_after_miss(self.weights, self.d[i])
        p = region_probabilities(self.labels, w, len(self.region_names))
        return dict(zip(self.region_names + (ELSEWHERE,), p.tolist())), w


def person_hides(est, obj: int) -> np.ndarray:
    """``(K,)``: the probability, per particle, that the person keeps object ``obj`` hidden (it is
    held by a tracked hand that carried it away and has stayed unseen in view, see
    :func:`~estimator.model.likelihood.hidden_by_person`); 0 for particles that do not hold it, and for a
    hand that has not moved since the object was seen (``NoiseConfig.hand_occlusion``). A look
    cannot find what the person hides, whatever the ray tests say: the filter's negative evidence
    and the plan then agree."""
    s = est.state
    held = is_held(s.modes[:, obj])
    if est.memory.hold_hand[obj] is None or not held.any():
        return np.zeros(len(held))
    nz = est.config.noise
    travel = est.memory.hand_travel()[obj]  # a hand that has not moved since cannot hide it (config)
    h = nz.hand_occlusion if (nz.hand_occlusion >= 1.0 or travel > est.config.priors.carry_distance) else 0.0
    return np.where(held, hidden_by_person(s.unseen_in_view[:, obj], h, nz.miss_prob), 0.0)


def search_regions(est, boxes: np.ndarray, hands, user: ViewpointFile | None, camera_xy) -> list[Region]:
    """The user's box regions, then (unless they replace them) the scene's derived ones."""
    own = list(user.regions) if user is not None else []
    if user is not None and user.replace_regions:
        return own
    return own + derive_regions(est.scene, boxes, hands, camera_xy)


def plan_search(est, object_id: str, viewpoints: ViewpointFile | list[Viewpoint] | None = None,
                config: SearchConfig | None = None, rng: np.random.Generator | None = None,
                hands: dict | None = None, start: np.ndarray | None = None, boxes: np.ndarray | None = None,
                reference: np.ndarray | None = None) -> SearchPlan:
    """The search plan for ``object_id`` from a :class:`~estimator.filter.SceneEstimator`'s present
    particles (its pool's worlds answer the ray tests).

    Args:
        viewpoints: candidate viewpoints (a list, or a :class:`ViewpointFile` with costs, start and
            regions); None: sampled around the likely regions with ``rng``.
        config: costs, detection model, sampling (defaults: :class:`SearchConfig`; the detection
            model defaults to the estimator's ``miss_prob`` and ``visibility_threshold``).
        hands: the tracked hands of the last frame (name -> position), for "held by" regions.
        start: where the camera is (default: the file's ``start``, else the scene camera, else the
            first viewpoint).
        boxes: the scene's AABBs ``(M, 2, 3)`` at its given poses (None: the estimator's pool's,
            read when it built its worlds; :func:`~.looks.static_boxes` reads them alone).
        reference: where the robot looks from ``(3,)``, naming the floor cells ("behind the table"
            is away from it; default: the scene camera, else ``start``): fixed while the camera
            moves, so that a region keeps its name over a search.
    Raises KeyError for an object the scene does not have, ValueError for one never perceived.
    """
    config = config or SearchConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    if object_id not in est.object_ids:
        raise KeyError(f"unknown object {object_id!r} (the scene has: {', '.join(est.object_ids)})")
    obj = list(est.object_ids).index(object_id)
    if not est.known[obj]:
        raise ValueError(f"object {object_id!r} has no pose yet: never perceived and none in the scene")
    user = viewpoints if isinstance(viewpoints, ViewpointFile) else None
    views = list(user.viewpoints if user is not None else viewpoints or [])
    fixed = user.fixed_cost if user is not None and user.fixed_cost is not None else config.fixed_cost
    per_m = user.travel_cost if user is not None and user.travel_cost is not None else config.travel_cost
    miss = config.miss_prob if config.miss_prob is not None else est.config.noise.miss_prob
    thr = config.visibility_threshold if config.visibility_threshold is not None else est.config.visibility_threshold
    boxes = est.pool.scene_boxes if boxes is None else boxes
    if start is None and user is not None:
        start = user.start
    if start is None and est.scene.camera is not None:
        start = np.asarray(est.scene.camera.position, float)
    ps = ParticleSet.from_estimator(est, hands)
    ti = table_of(est.scene, boxes)
    if reference is None and est.scene.camera is not None:
        reference = est.scene.camera.position
    if reference is None:
        reference = start if start is not None else DEFAULT_REFERENCE
    camera_xy = np.asarray(reference, float)[:2]
    regions = search_regions(est, boxes, ps.hands or {}, user, camera_xy)
    labels = assign(ps, obj, regions, boxes[ti] if ti is not None else None, camera_xy, est.scene.floor)
    probs = region_probabilities(labels, ps.weights, len(regions))
    likely = [r for r in np.argsort(-probs[:-1], kind="stable") if probs[r] >= max(config.min_region_p, 1e-12)]
    if not views:
        centres = []
        for r in likely:
            m = labels == r
            centres.append((regions[r].name, np.average(ps.poses[m, obj, :3], axis=0, weights=ps.weights[m])))
        views = sample_viewpoints(centres, config, rng)
    if start is None:
        start = views[0].position if views else np.zeros(3)
    D = detection(est.pool, ps, obj, est.known, views, miss, thr)  # (V, K)
    D = D * (1.0 - person_hides(est, obj))[None, :]
    first_cost = travel_costs(start, views, fixed, per_m)[-1] if views else np.zeros(0)
    chosen: dict[int, list[str]] = {}
    for r in likely:
        m = labels == r
        d_r = D[:, m] @ ps.weights[m] / probs[r]  # (V,) P(found | in region r)
        if len(d_r) and d_r.max() > MIN_DETECTION:
            chosen.setdefault(int(np.argmax(d_r / first_cost)), []).append(regions[r].name)
    look_views = [views[v] for v in chosen]
    d = D[list(chosen)] if chosen else np.zeros((0, len(ps.weights)))
    cost = travel_costs(start, look_views, fixed, per_m)
    order, expected, method = plan_order(d, ps.weights, cost, config.exact_max_looks)
    cond, first = find_probabilities(order, d, ps.weights)
    looks, prev = [], len(look_views)
    for i, v in enumerate(order):
        looks.append(PlannedLook(look_views[v], tuple(chosen[list(chosen)[v]]), float(cond[i]), float(first[i]),
                                 float(cost[prev, v])))
        prev = v
    names = tuple(r.name for r in regions)
    ranked = sorted(zip(names, probs[:-1].tolist()), key=lambda x: -x[1])
    ranked = [(n, p) for n, p in ranked if p > 0] + [(ELSEWHERE, float(probs[-1]))]
    return SearchPlan(object_id, est.last_belief.t if est.last_belief is not None else None, ranked, looks,
                      expected, float(first.sum()), method, ps.weights, labels, names, d[order], len(views))


def look_at_point(est, object_id: str, point, config: SearchConfig | None = None,
                  rng: np.random.Generator | None = None, start=None, label: str = "point") -> PlannedLook:
    """The best look for ``object_id`` if it were at ``point (3,)`` (m), for a searcher that only has
    a point guess (a last-seen place, a single-world estimate): ``config.views_per_region``
    viewpoints sampled around the point, each one's probability of finding the object there by ray
    tests in the estimator's worlds with the object moved to the point (everything else as each
    particle has it), and the viewpoint with the largest probability per unit of cost from ``start``
    (default: the scene camera). ``label`` names the look's region."""
    config = config or SearchConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    obj = list(est.object_ids).index(object_id)
    point = np.asarray(point, float).reshape(3)
    if start is None:
        start = est.scene.camera.position if est.scene.camera is not None else DEFAULT_REFERENCE
    ps = ParticleSet.from_estimator(est)
    poses = ps.poses.copy()
    poses[:, obj, :3] = point
    ps = replace(ps, poses=poses)
    known = np.asarray(est.known, bool).copy()
    known[obj] = True
    miss = config.miss_prob if config.miss_prob is not None else est.config.noise.miss_prob
    thr = config.visibility_threshold if config.visibility_threshold is not None else est.config.visibility_threshold
    views = sample_viewpoints([(label, point)], config, rng)
    p = detection(est.pool, ps, obj, known, views, miss, thr) @ ps.weights  # (V,)
    cost = travel_costs(np.asarray(start, float), views, config.fixed_cost, config.travel_cost)[-1]
    v = int(np.argmax(p / cost))
    return PlannedLook(views[v], (label,), float(p[v]), float(p[v]), float(cost[v]))


class ClosedLoopSearch:
    """The closed loop: plan, look, and on a miss feed the look to the estimator and plan again.

    ``search.plan()`` gives the present plan; ``search.look_failed(plan.looks[0], seen)`` feeds the
    estimator a frame at its next reasoning time, taken by that look's camera, in which the object
    is absent (``seen``: detections of other objects made on the way, by id), and moves the camera
    there (the next plan's travel starts from it). Randomness: ``rng`` (sampled viewpoints)."""

    def __init__(self, est, object_id: str, viewpoints=None, config: SearchConfig | None = None,
                 rng: np.random.Generator | None = None, hands: dict | None = None, start=None):
        self.est, self.object_id, self.viewpoints = est, object_id, viewpoints
        self.config = config or SearchConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.hands = dict(hands or {})
        self.start = None if start is None else np.asarray(start, float)
        if self.start is None and isinstance(viewpoints, ViewpointFile):
            self.start = viewpoints.start
        if self.start is None and est.scene.camera is not None:
            self.start = np.asarray(est.scene.camera.position, float)
        # region names stay those seen from where the search began (no camera, no start: from +x)
        self.reference = self.start if self.start is not None else np.array(DEFAULT_REFERENCE)
        self.boxes = est.pool.scene_boxes
        self.looks_done: list[PlannedLook] = []

    def plan(self) -> SearchPlan:
        plan = plan_search(self.est, self.object_id, self.viewpoints, self.config, self.rng, self.hands,
                           self.start, self.boxes, self.reference)
        return plan

    def next_time(self) -> float:
        """The stream time of the next look's frame: the estimator's next reasoning step."""
        est = self.est
        last = max(t for t in (est.t_frame, est.t_tick, 0.0) if t is not None)
        return last + est.config.reasoner.horizon + 1e-6

    def look_failed(self, look: PlannedLook, seen: dict[str, Detection] | None = None, t: float | None = None):
        """Feed the failed ``look`` to the estimator; returns its new belief."""
        if seen and self.object_id in seen:
            raise ValueError(f"{self.object_id!r} was seen: the look did not fail")
        frame = Frame(self.next_time() if t is None else float(t), dict(seen or {}),
                      {k: np.asarray(v, float) for k, v in self.hands.items() if v is not None},
                      cameras={look.viewpoint.id: look.viewpoint.camera})
        belief = self.est.update(frame)
        self.start = look.viewpoint.position
        self.looks_done.append(look)
        return belief
