"""One search trial: a scenario's seeded variant, the object it hides at the end, and every search
method looking for it with a simulated robot camera.

The scenario is simulated (:func:`experiments.simulation.simulator.open_simulation`) and its
ground-truth world kept open in its final state; the *target* is the dynamic object that is not
visible to the scene camera at the end (of several, the one that moved farthest from where it
started: the interesting one). Each method then produces looks, one at a time; a look is a camera
pose; the truth world decides whether it sees the target (its visible fraction reaches the
scenario's perception threshold, hand and torso occluding). A method gets at most
:data:`MAX_LOOKS` looks. A look costs ``SearchConfig.fixed_cost`` plus ``travel_cost`` per metre
the camera moves from the previous viewpoint (the first from the scene camera): the same rule for
every method.

======================  ===========================================================================
method                  looks
======================  ===========================================================================
``closed-loop``         :class:`~estimator.applications.search.ClosedLoopSearch` on the particle estimator: the
                        plan's first look; on a miss the look is fed to the estimator as a frame
                        (with the other objects it saw) and the plan is made again
``open-loop``           the particle estimator's first plan, look after look (Bayes' rule on the
                        particle weights only)
``paper-first``         a look at the paper's reasoner's position of the object
``last-seen-first``     a look at where the object was last perceived
``random``              the scene's search regions in a uniformly random order
======================  ===========================================================================

When a method has no look left (a plan exhausted, a baseline after its first look), it goes on
with the regions it has not looked at, in a random order (seeded per trial and method), each
looked at from the viewpoint :func:`~estimator.applications.search.look_at_point` picks in that method's worlds
(the paper's reasoner's world for the baselines). Regions and their points are those a searcher
without particles would use (:func:`region_points`).
"""
from __future__ import annotations

import time
import zlib
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from estimator.applications.search import ClosedLoopSearch, PlannedLook, SearchConfig, look_at_point, plan_search
from estimator.applications.search.regions import derive_regions, table_of
from estimator.config import EstimatorConfig
from estimator.filter import SceneEstimator
from estimator.observations import Detection, parse_frame
from experiments.evaluation.methods import method_config
from experiments.simulation.simulator import open_simulation

SEARCH_METHODS = ("closed-loop", "open-loop", "paper-first", "last-seen-first", "random")
MAX_LOOKS = 6
"""Looks a method gets; a target not found by then counts ``MAX_LOOKS + 1`` looks (censored)."""
ROW_VERSION = 1
LOOK_CONFIG = SearchConfig(fov_deg=30.0, view_distance=0.7)
"""The robot's looks in the experiment: a 30 degree field of view from 0.7 m, so that one look covers
one place (from the default 1 m with 60 degrees, a look at the top of a box also sees the floor
behind it, and every method finds most objects at once). The same for every method."""
FLOOR_MARGIN = 0.3
"""How far beyond the table's edge (m) a baseline looks for an object on the floor."""


@dataclass(frozen=True)
class SearchTrialSpec:
    """One trial: ``scenario`` and ``seed`` (all methods run in it, on the same simulation),
    ``particles`` of the particle estimator, ``duration`` (s) overriding the scenario's."""

    scenario: str
    seed: int
    particles: int = 64
    duration: float | None = None

    @property
    def key(self) -> str:
        d = "full" if self.duration is None else f"{self.duration:g}s"
        return f"search__{self.scenario}__s{self.seed}__K{self.particles}__{d}"


def _rng(seed: int, *names: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed)] + [zlib.crc32(n.encode()) for n in names]))


def choose_target(result) -> str | None:
    """The object to search for: a dynamic object not visible at the end of ``result``'s truth;
    of several, the one farthest (m) from its initial position. ``None`` when every one is seen."""
    last = result.truth[-1]["objects"]
    best, far = None, -1.0
    for i, spec in enumerate(result.scene.objects):
        if spec.static or last[spec.id]["visible"]:
            continue
        d = float(np.linalg.norm(np.asarray(last[spec.id]["position"]) - result.initial_poses[i, :3]))
        if d > far:
            best, far = spec.id, d
    return best


def region_points(est: SceneEstimator, hands: dict, target: str | None = None) -> list[tuple[str, np.ndarray]]:
    """``(name, point (3,))`` for each search region of ``est``'s scene, as a searcher without
    particles would aim: the centre of a container, 3 cm above the middle of a support's top (its
    box at the estimator's mean pose for dynamic objects), :data:`FLOOR_MARGIN` beyond the table's
    edge on the floor (under it: its centre), a tracked hand's last position. Regions on or in the
    ``target`` itself are left out."""
    scene = est.scene
    boxes = est.pool.scene_boxes.copy()  # at the scene's poses, as the worlds were built
    belief = est.last_belief
    for i, spec in enumerate(scene.objects):  # dynamic objects: their box where the estimate puts them
        if not spec.static and belief is not None and spec.id in belief.objects:
            shift = np.asarray(belief.objects[spec.id].position) - 0.5 * (boxes[i, 0] + boxes[i, 1])
            boxes[i] = boxes[i] + shift
    cam = np.asarray(scene.camera.position if scene.camera is not None else (10.0, 0.0, 0.0), float)
    out = []
    ti = table_of(scene, boxes)
    for reg in derive_regions(scene, boxes, tuple(hands), cam[:2]):
        if reg.support is not None and reg.support == target:
            continue
        if reg.kind in ("in", "on"):
            b = boxes[scene.index(reg.support)]
            c = 0.5 * (b[0] + b[1])
            out.append((reg.name, c if reg.kind == "in" else np.array([c[0], c[1], b[1, 2] + 0.03])))
        elif reg.kind == "floor" and ti is not None:
            b = boxes[ti]
            c = 0.5 * (b[0] + b[1])
            sight = c[:2] - cam[:2]
            sight /= max(np.linalg.norm(sight), 1e-9)
            left = np.array([-sight[1], sight[0]])
            half = 0.5 * (b[1, :2] - b[0, :2])
            reach = np.abs(np.stack([sight, left])) @ half  # the table's half extents along sight, left
            step = {"under": np.zeros(2), "behind": sight * (reach[0] + FLOOR_MARGIN),
                    "front": -sight * (reach[0] + FLOOR_MARGIN), "left": left * (reach[1] + FLOOR_MARGIN),
                    "right": -left * (reach[1] + FLOOR_MARGIN)}[reg.cell]
            out.append((reg.name, np.array([c[0] + step[0], c[1] + step[1], 0.05])))
        elif reg.kind == "held" and reg.hand is not None and hands.get(reg.hand) is not None:
            out.append((reg.name, np.asarray(hands[reg.hand], float)))
    return out


class TruthCamera:
    """Looks in the ground-truth world: whether a viewpoint sees the target, and the detections of
    the other dynamic objects it sees (true poses)."""

    def __init__(self, truth, target: str):
        self.truth = truth
        self.ids = truth.world.object_ids
        self.target = self.ids.index(target)
        self.threshold = truth.scenario.perception.visibility_threshold
        self.poses = truth.world.get_poses()
        self.static = np.array(truth.world.static, dtype=bool)

    def look(self, look: PlannedLook) -> tuple[bool, dict[str, Detection]]:
        frac = self.truth.look(look.viewpoint.camera)
        seen = {self.ids[i]: Detection(self.poses[i, :3].copy(), self.poses[i, 3:].copy())
                for i in np.flatnonzero((frac >= self.threshold) & ~self.static) if i != self.target}
        return bool(frac[self.target] >= self.threshold), seen


def _run_stream(scene, frames, cfg: EstimatorConfig, rng) -> SceneEstimator:
    est = SceneEstimator(scene, cfg, rng)
    try:
        for f in frames:
            est.update(f)
    except BaseException:
        est.close()
        raise
    return est


def search_with(next_look: Callable[[], PlannedLook | None], on_miss: Callable[[PlannedLook, dict], None],
                truth: TruthCamera, start: np.ndarray, config: SearchConfig) -> dict:
    """Take looks from ``next_look`` until the truth sees the target or :data:`MAX_LOOKS` are used;
    ``on_miss(look, seen)`` after each failed one. Returns the row part of one method: ``found``,
    ``looks`` (``MAX_LOOKS + 1`` when not found), ``cost`` (of the looks made until found; all
    made when not), ``first_p`` (the method's own probability that its first look finds it, NaN for
    none), the viewpoints and the planning time (ms, mean per look)."""
    pos, cost, views, plan_s = np.asarray(start, float), 0.0, [], []
    first_p = float("nan")
    for i in range(MAX_LOOKS):
        t0 = time.perf_counter()
        look = next_look()
        plan_s.append(time.perf_counter() - t0)
        if look is None:
            break
        if i == 0:
            first_p = look.p_find
        cost += config.fixed_cost + config.travel_cost * float(np.linalg.norm(look.viewpoint.position - pos))
        pos = look.viewpoint.position
        views.append({"id": look.viewpoint.id, "regions": list(look.regions)})
        found, seen = truth.look(look)
        if found:
            return {"found": True, "looks": i + 1, "cost": cost, "first_p": first_p, "views": views,
                    "planning_ms": 1e3 * float(np.mean(plan_s))}
        on_miss(look, seen)
    return {"found": False, "looks": MAX_LOOKS + 1, "cost": cost, "first_p": first_p, "views": views,
            "planning_ms": 1e3 * float(np.mean(plan_s)) if plan_s else float("nan")}


class _Fallback:
    """The regions not yet looked at, in a random order, each looked at with
    :func:`look_at_point` in ``est``'s worlds."""

    def __init__(self, est, target, hands, config, rng):
        self.est, self.target, self.config, self.rng = est, target, config, rng
        self.points = region_points(est, hands, target)
        self.todo = [self.points[i] for i in rng.permutation(len(self.points))]
        self.done: set[str] = set()
        self.start = None

    def looked(self, look: PlannedLook) -> None:
        self.done.update(look.regions)
        self.start = look.viewpoint.position

    def next(self) -> PlannedLook | None:
        while self.todo:
            name, point = self.todo.pop(0)
            if name not in self.done:
                return look_at_point(self.est, self.target, point, self.config, self.rng, self.start, label=name)
        return None


def _region_of(pts: list[tuple[str, np.ndarray]], point) -> str | None:
    """The region a baseline's point lies in: the nearest of the region points ``pts`` (the
    baseline's look is counted as a look at that region)."""
    if not pts:
        return None
    d = [np.linalg.norm(p - point) for _n, p in pts]
    return pts[int(np.argmin(d))][0]


def _baseline(est, target, point, hands, config, rng, truth, start, label) -> dict:
    fb = _Fallback(est, target, hands, config, rng)
    first = [look_at_point(est, target, point, config, rng, start, label=_region_of(fb.points, point) or label)
             ] if point is not None else []

    def next_look():
        look = first.pop(0) if first else fb.next()
        if look is not None:
            fb.looked(look)
        return look

    return search_with(next_look, lambda look, seen: None, truth, start, config)


def run_search_trial(spec: SearchTrialSpec, methods=SEARCH_METHODS, config: SearchConfig | None = None) -> dict:
    """Run every method of ``methods`` on ``spec``; returns ``{"row": row}`` (the evaluation
    sweep's format). The row: ``key``, ``scenario``, ``seed``, ``particles``, ``target`` (None when
    the scenario hid nothing at the end: no search), and per method the dict of
    :func:`search_with`; ``timing`` (wall clock) apart."""
    config = config or LOOK_CONFIG
    t_start = time.perf_counter()
    row = {"key": spec.key, "scenario": spec.scenario, "seed": spec.seed, "particles": spec.particles,
           "duration": spec.duration, "version": ROW_VERSION, "methods": {}}
    with open_simulation(spec.scenario, spec.seed, spec.duration) as (result, truth):
        target = choose_target(result)
        row["target"] = target
        if target is None:
            row["timing"] = {"trial_s": time.perf_counter() - t_start}
            return {"row": row}
        scene = result.scene
        frames = [parse_frame(f, known_ids=scene.object_ids) for f in result.observations]
        hands = {k: np.asarray(v, float) for k, v in frames[-1].hands.items()} if frames else {}
        start = np.asarray(scene.camera.position, float)
        eye = TruthCamera(truth, target)
        todo = set(methods)
        paper_cfg = method_config("paper", 1)
        with _run_stream(scene, frames, paper_cfg, _rng(spec.seed, "paper")) as paper:
            if "paper-first" in todo:
                pos = paper.last_belief.objects[target].position if paper.last_belief is not None else None
                row["methods"]["paper-first"] = _baseline(paper, target, pos, hands, config,
                                                          _rng(spec.seed, "paper-first"), eye, start, "paper")
            if "last-seen-first" in todo:
                seen = [f.objects[target].position for f in frames if target in f.objects]
                pos = seen[-1] if seen else np.asarray(scene.objects[scene.index(target)].position, float)
                row["methods"]["last-seen-first"] = _baseline(paper, target, pos, hands, config,
                                                              _rng(spec.seed, "last-seen-first"), eye, start,
                                                              "last seen")
            if "random" in todo:
                row["methods"]["random"] = _baseline(paper, target, None, hands, config, _rng(spec.seed, "random"),
                                                     eye, start, "random")
        cfg = method_config("particles", spec.particles)  # its worlds in this process
        for name in ("open-loop", "closed-loop"):
            if name not in todo:
                continue
            rng = _rng(spec.seed, name)
            with _run_stream(scene, frames, cfg, _rng(spec.seed, "particles")) as est:
                row["methods"][name] = (_open_loop if name == "open-loop" else _closed_loop)(
                    est, target, hands, config, rng, eye, start)
    row["timing"] = {"trial_s": time.perf_counter() - t_start}
    return {"row": row}


def _open_loop(est, target, hands, config, rng, eye, start) -> dict:
    fb = _Fallback(est, target, hands, config, rng)
    t0 = time.perf_counter()
    plan = plan_search(est, target, None, config, rng, hands, start)
    plan_ms = 1e3 * (time.perf_counter() - t0)
    queue: Iterator[PlannedLook] = iter(plan.looks)

    def next_look():
        look = next(queue, None) or fb.next()
        if look is not None:
            fb.looked(look)
        return look

    out = search_with(next_look, lambda look, seen: None, eye, start, config)
    out["plan_looks"] = len(plan.looks)
    out["planning_ms"] = plan_ms  # the one plan (the looks after it only read it)
    return out


def _closed_loop(est, target, hands, config, rng, eye, start) -> dict:
    search = ClosedLoopSearch(est, target, None, config, rng, hands, start)
    fb = _Fallback(est, target, hands, config, rng)

    def next_look():
        plan = search.plan()
        look = plan.looks[0] if plan.looks else fb.next()
        if look is not None:
            fb.looked(look)
        return look

    def on_miss(look, seen):
        search.look_failed(look, seen)
        fb.start = look.viewpoint.position

    return search_with(next_look, on_miss, eye, start, config)
