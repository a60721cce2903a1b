"""One search trial (experiments.search.trial): the target, the regions a searcher without particles
aims at, the look loop's counting, and a whole trial's reproducibility."""
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.applications.search import PlannedLook, SearchConfig, Viewpoint
from estimator.applications.search.looks import static_boxes
from estimator.config import EstimatorConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.search.trial import (
    FLOOR_MARGIN,
    MAX_LOOKS,
    SearchTrialSpec,
    choose_target,
    region_points,
    run_search_trial,
    search_with,
)
from helpers import TABLE_TOP, table_scene
from physics.scene import CameraSpec

BIN = {"id": "bin", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01},
       "pose": {"position": [0.2, -0.3, TABLE_TOP + 0.06]}}
CUP = {"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.05]}}
BALL = {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [-0.2, 0.2, TABLE_TOP + 0.03]}}
CAMERA = {"position": [1.5, 0.0, 1.2], "target": [0.0, 0.0, 0.7]}


def _result(visible: dict, moved: dict):
    scene = table_scene(BIN, CUP, BALL, camera=CAMERA)
    init = np.zeros((4, 7))
    last = {}
    for i, o in enumerate(scene.objects):
        init[i, :3] = o.position
        last[o.id] = {"position": list(np.add(o.position, [moved.get(o.id, 0.0), 0, 0])),
                      "visible": visible.get(o.id, True)}
    return SimpleNamespace(scene=scene, initial_poses=init, truth=[{"t": 1.0, "objects": last}])


def test_the_target_is_the_hidden_dynamic_object_that_moved_farthest():
    assert choose_target(_result({}, {})) is None  # everything in view: nothing to search
    assert choose_target(_result({"cup": False}, {})) == "cup"
    assert choose_target(_result({"cup": False, "ball": False}, {"ball": 0.5, "cup": 0.1})) == "ball"
    assert choose_target(_result({"table": False, "cup": False}, {"table": 2.0})) == "cup"  # static: never


def test_region_points_aim_at_each_region_but_the_targets_own():
    scene = table_scene(BIN, CUP, BALL, camera=CAMERA)
    with SceneEstimator(scene, EstimatorConfig.paper(), np.random.default_rng(0)) as est:
        est.update(Frame(0.0, {}))
        pts = dict(region_points(est, {"human/right": np.array([0.3, 0.4, 1.0])}, target="cup"))
        assert "on cup" not in pts and "inside bin" in pts and "on ball" in pts
        boxes = static_boxes(scene)
        table, binbox = boxes[0], boxes[1]
        assert np.allclose(pts["inside bin"], binbox.mean(axis=0), atol=0.01)  # (the filter settles it)
        assert pts["on table"][2] == pytest.approx(table[1, 2] + 0.03)
        # the camera is at +x: "behind the table" is beyond its -x edge, "in front" beyond +x
        assert pts["floor, behind the table"][0] == pytest.approx(table[0, 0] - FLOOR_MARGIN)
        assert pts["floor, in front of the table"][0] == pytest.approx(table[1, 0] + FLOOR_MARGIN)
        assert pts["floor, left of the table"][1] == pytest.approx(table[0, 1] - FLOOR_MARGIN)
        assert np.allclose(pts["held by human/right"], [0.3, 0.4, 1.0])


def _look(name, x):
    return PlannedLook(Viewpoint(name, CameraSpec(position=(x, 0.0, 1.0), target=(0.0, 0.0, 0.7))), (name,),
                       0.5, 0.5, 0.0)


class _Truth:
    def __init__(self, finds):
        self.finds = finds

    def look(self, look):
        return look.viewpoint.id in self.finds, {}


def test_looks_are_counted_and_costed_alike_for_every_method():
    cfg = SearchConfig(fixed_cost=1.0, travel_cost=2.0)
    looks = iter([_look("a", 1.0), _look("b", 3.0), _look("c", 0.0)])
    missed = []
    out = search_with(lambda: next(looks, None), lambda lk, seen: missed.append(lk.viewpoint.id),
                      _Truth({"c"}), np.array([0.0, 0.0, 1.0]), cfg)
    assert out["found"] and out["looks"] == 3 and missed == ["a", "b"]
    assert out["cost"] == pytest.approx(3 * 1.0 + 2.0 * (1.0 + 2.0 + 3.0))
    # never found: censored at MAX_LOOKS + 1, every look paid; a method out of looks stops early
    endless = search_with(lambda: _look("a", 0.0), lambda lk, seen: None, _Truth(set()), np.zeros(3), cfg)
    assert not endless["found"] and endless["looks"] == MAX_LOOKS + 1 and len(endless["views"]) == MAX_LOOKS
    none = search_with(lambda: None, lambda lk, seen: None, _Truth(set()), np.zeros(3), cfg)
    assert none["looks"] == MAX_LOOKS + 1 and none["cost"] == 0.0 and np.isnan(none["first_p"])


def test_a_trial_is_reproducible_and_counts_its_looks():
    spec = SearchTrialSpec("ball_dropped_into_box", 0, particles=4, duration=2.5)
    a = run_search_trial(spec)["row"]
    b = run_search_trial(spec)["row"]
    assert a["target"] == "ball"
    strip = lambda row: {m: {k: v for k, v in r.items() if k != "planning_ms"} for m, r in row["methods"].items()}
    assert strip(a) == strip(b)
    assert set(a["methods"]) == {"closed-loop", "open-loop", "paper-first", "last-seen-first", "random"}
    for r in a["methods"].values():
        assert r["found"] == (r["looks"] <= MAX_LOOKS)
        if r["found"]:
            assert len(r["views"]) == r["looks"]
