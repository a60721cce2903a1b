import json
import math

import numpy as np
import pytest

from actions.modes import HELD
from estimator.applications.search import (
    ClosedLoopSearch,
    ParticleSet,
    Region,
    SearchConfig,
    Viewpoint,
    ViewpointError,
    plan_search,
    read_viewpoints,
)
from estimator.applications.search.looks import static_boxes, travel_costs
from estimator.applications.search.plan import (
    bayes_after_miss,
    brute_force_order,
    exact_order,
    expected_cost,
    greedy_order,
    plan_order,
)
from estimator.applications.search.regions import assign, derive_regions, region_probabilities, table_of
from estimator.config import EstimatorConfig, NoiseConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.cli import main
from helpers import TABLE_TOP, table_scene, write_jsonl
from physics.scene import CameraSpec

CUP = {"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.05]}}
BIN = {"id": "bin", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01},
       "pose": {"position": [0.2, -0.3, TABLE_TOP + 0.06]}}
BLOCK = {"id": "block", "box": {"size": [0.1, 0.1, 0.1]}, "pose": {"position": [-0.2, 0.3, TABLE_TOP + 0.05]}}


# -- regions -----------------------------------------------------------------------------------------------

def test_region_probabilities_and_elsewhere_sum_to_one_and_equal_hand_built_sums():
    scene = table_scene(BIN, CUP, BLOCK)  # table 0, bin 1, cup 2, block 3
    boxes = static_boxes(scene)
    table_box = boxes[table_of(scene, boxes)]
    cam_xy = np.array([3.0, 0.0])  # the robot looks from +x: "behind the table" is -x
    shelf = Region("shelf", "box", box=((-0.1, 0.5, 0.6), (0.1, 0.7, 1.0)))
    regions = [shelf] + derive_regions(scene, boxes, ["human/right"], cam_xy)
    names = [r.name for r in regions]
    # one particle per case, expected region by hand
    cases = [  # (position, mode, relation, expected region)
        ([0.3, 0.0, 1.0], HELD, None, "held by human/right"),
        ([0.2, -0.3, 0.68], 0, ("in", 1), "inside bin"),
        ([0.0, 0.0, 0.68], 0, ("on", 0), "on table"),
        ([-0.2, 0.3, 0.73], 0, ("on", 3), "on block"),
        ([-1.5, 0.1, 0.05], 0, ("on", 4), "floor, behind the table"),
        ([1.5, -0.2, 0.05], 0, ("on", 4), "floor, in front of the table"),
        ([0.0, 0.0, 0.05], 0, ("on", 4), "floor, under the table"),
        ([0.1, -1.6, 0.05], 0, ("on", 4), "floor, left of the table"),
        ([0.1, 1.6, 0.05], 0, ("on", 4), "floor, right of the table"),
        ([0.0, 0.6, 0.8], 0, ("on", 0), "shelf"),  # in the user's box, whatever its support
        ([0.0, 0.0, 1.5], 0, None, "elsewhere"),  # in the air, not held
    ]
    K, M = len(cases) * 3, 4
    poses = np.zeros((K, M, 7))
    poses[..., 6] = 1.0
    modes = np.zeros((K, M), np.int8)
    on_top, is_in = np.zeros((K, M, M + 1), bool), np.zeros((K, M, M), bool)
    expected = []
    for k in range(K):
        pos, mode, rel, name = cases[k % len(cases)]
        poses[k, 2, :3] = pos
        modes[k, 2] = mode
        if rel is not None:
            (on_top if rel[0] == "on" else is_in)[k, 2, rel[1]] = True
        expected.append(name)
    w = np.random.default_rng(3).random(K)
    w /= w.sum()
    ps = ParticleSet(poses, w, modes, on_top, is_in, tuple(scene.object_ids), (None, None, "human/right", None),
                     {"human/right": np.zeros(3)})
    labels = assign(ps, 2, regions, table_box, cam_xy)
    got = [names[i] if i < len(names) else "elsewhere" for i in labels]
    assert got == expected
    probs = region_probabilities(labels, w, len(regions))
    assert math.isclose(probs.sum(), 1.0, abs_tol=1e-12)
    for r, name in enumerate(names + ["elsewhere"]):
        assert math.isclose(probs[r], sum(w[k] for k in range(K) if expected[k] == name), abs_tol=1e-12)


# -- the plan ----------------------------------------------------------------------------------------------

def _random_case(rng, L, K=12):
    d = rng.random((L, K)) * (rng.random((L, K)) < 0.6)
    w = rng.random(K)
    views = [Viewpoint(str(i), CameraSpec(position=tuple(rng.uniform(-2, 2, 3)), target=(0, 0, 0))) for i in range(L)]
    return d, w / w.sum(), travel_costs(rng.uniform(-2, 2, 3), views, 0.5, 1.0)


def test_the_exact_look_order_equals_the_brute_force_optimum_and_greedy_is_never_better():
    rng = np.random.default_rng(0)
    greedy_worse = 0
    for L in range(1, 7):
        for _ in range(8):
            d, w, cost = _random_case(rng, L)
            order, value = exact_order(d, w, cost)
            best, best_value = brute_force_order(d, w, cost)
            assert sorted(order) == list(range(L))
            assert math.isclose(value, best_value, rel_tol=1e-9, abs_tol=1e-12)
            assert math.isclose(expected_cost(order, d, w, cost), value, rel_tol=1e-9, abs_tol=1e-12)
            g = greedy_order(d, w, cost)[1]
            assert g >= value - 1e-12
            greedy_worse += g > value + 1e-9
    assert greedy_worse > 0  # with travel costs the greedy rule is not optimal: the exact search matters
    d, w, cost = _random_case(rng, 10)
    assert plan_order(d, w, cost, exact_max=8)[2] == "greedy" and plan_order(d[:8], w, cost[:, :8][[*range(8), 10]])[2] == "exact"


def test_expected_cost_is_the_mean_cost_of_simulated_searches():
    rng = np.random.default_rng(1)
    d, w, cost = _random_case(rng, 4)
    order = exact_order(d, w, cost)[0]
    n = 40000
    truth = rng.choice(len(w), size=n, p=w)
    paid = np.zeros(n)
    found = np.zeros(n, bool)
    prev = d.shape[0]
    for v in order:
        paid += np.where(found, 0.0, cost[prev, v])
        found |= rng.random(n) < d[v, truth]
        prev = v
    se = paid.std() / math.sqrt(n)
    assert abs(paid.mean() - expected_cost(order, d, w, cost)) < 4 * se


# -- with the estimator: open and closed loop --------------------------------------------------------------

FLOOR_VIEW = Viewpoint("floor", CameraSpec(position=(-1.9, 0.0, 0.7), target=(-1.05, 0.0, 0.0)))  # sees no table top
TABLE_VIEW = Viewpoint("table", CameraSpec(position=(0.9, 0.0, 1.5), target=(0.0, 0.0, TABLE_TOP)))


def _split_estimator(K=64, seed=0, resample_threshold=1.0):
    """An estimator whose cup is on the floor behind the table (-x) in 40 % of the particles, on the
    table in the others; no scene camera; no noise (nothing moves but what the filter does)."""
    scene = table_scene(CUP)
    cfg = EstimatorConfig(particles=K, noise=NoiseConfig.off(), resample_threshold=resample_threshold, workers=0)
    est = SceneEstimator(scene, cfg, np.random.default_rng(seed))
    est.update(Frame(0.0, {}))
    rng = np.random.default_rng(seed + 1)
    cup = est.object_ids.index("cup")
    n_floor = int(0.4 * K)
    est.state.poses[:n_floor, cup, :3] = np.c_[rng.uniform(-1.2, -0.9, n_floor), rng.uniform(-0.4, 0.4, n_floor),
                                                np.full(n_floor, 0.05)]
    est.state.poses[n_floor:, cup, :3] = np.c_[rng.uniform(-0.3, 0.3, K - n_floor), rng.uniform(-0.3, 0.3, K - n_floor),
                                                np.full(K - n_floor, TABLE_TOP + 0.05)]
    est.update(Frame(0.08, {}))  # physics settles them and computes their supports
    return est


def test_open_loop_probabilities_after_a_failed_look_follow_bayes_rule_exactly():
    with _split_estimator(resample_threshold=0.0) as est:
        plan = plan_search(est, "cup", [FLOOR_VIEW, TABLE_VIEW], rng=np.random.default_rng(0))
        p = dict(plan.regions)
        assert math.isclose(sum(p.values()), 1.0, abs_tol=1e-12)
        n_floor = int(0.4 * 64)
        assert p["floor, behind the table"] == pytest.approx(n_floor / 64, abs=1e-12)
        assert p["on table"] == pytest.approx(1 - n_floor / 64, abs=1e-12)
        for i, look in enumerate(plan.looks):
            after, w = plan.after_miss(i)
            names = plan.region_names + ("elsewhere",)
            # region-level Bayes: p_r (1 - D_r) / (1 - sum_s p_s D_s), D_r the look's detection given r
            D = {n: (plan.weights[plan.labels == j] @ plan.d[i][plan.labels == j]) / p[n]
                 for j, n in enumerate(names) if p.get(n, 0) > 0}
            norm = 1.0 - sum(p[n] * D[n] for n in D)
            for n in D:
                assert after[n] == pytest.approx(p[n] * (1 - D[n]) / norm, abs=1e-12)
            assert math.isclose(sum(after.values()), 1.0, abs_tol=1e-12)
            assert np.allclose(w, bayes_after_miss(plan.weights, plan.d[i]))
        assert {lk.viewpoint.id: lk.regions for lk in plan.looks} == {"floor": ("floor, behind the table",),
                                                                      "table": ("on table",)}
        floor_look = plan.looks[[lk.viewpoint.id for lk in plan.looks].index("floor")]
        table_d = plan.d[[lk.viewpoint.id for lk in plan.looks].index("floor")][plan.labels == plan.region_names.index("on table")]
        assert np.all(table_d == 0)  # the floor view sees no table particle, and every floor particle:
        assert floor_look.p_first == pytest.approx((1 - est.config.noise.miss_prob) * n_floor / 64, abs=1e-12)


def test_closed_loop_a_failed_look_lowers_the_region_by_the_miss_probability_of_the_ray_tests():
    K = 64
    with _split_estimator(K) as est:
        search = ClosedLoopSearch(est, "cup", [FLOOR_VIEW, TABLE_VIEW], rng=np.random.default_rng(0))
        plan = search.plan()
        i = [lk.viewpoint.id for lk in plan.looks].index("floor")
        predicted, _ = plan.after_miss(i)  # open loop: the ray tests' detection probabilities, Bayes' rule
        prior = plan.region_p("floor, behind the table")
        p_pred = predicted["floor, behind the table"]
        assert p_pred < prior - 0.2  # the look sees most of the floor particles: a real drop
        belief = search.look_failed(plan.looks[i])
        # before resampling, the filter's own negative evidence (its ray tests after physics, the
        # look's camera in the frame) gives the same weights: with no noise nothing moved
        cup = est.object_ids.index("cup")
        on_floor = belief.particles[:, cup, 2] < 0.3
        assert belief.weights[on_floor].sum() == pytest.approx(p_pred, abs=1e-9)
        # after (systematic) resampling the region's share is a count: its standard deviation is at
        # most the binomial sqrt(p (1 - p) / K); 3 of them is the band
        after = search.plan()
        # the region keeps its name while the camera moves: all floor particles are still in it
        assert after.region_p("floor, behind the table") == pytest.approx(np.mean(est.state.poses[:, cup, 2] < 0.3))
        band = 3 * math.sqrt(p_pred * (1 - p_pred) / K) + 1 / K
        assert abs(after.region_p("floor, behind the table") - p_pred) <= band
        assert after.region_p("floor, behind the table") < prior


# -- the command line --------------------------------------------------------------------------------------

@pytest.fixture
def stream(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text(json.dumps({"name": "s", "camera": {"position": [1.5, 0, 1.2], "target": [0, 0, 0.6]},
                                 "objects": [{"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
                                              "pose": {"position": [0, 0, 0]}}, CUP]}))
    obs = tmp_path / "o.jsonl"
    write_jsonl(obs, [{"t": round(0.04 * i, 2), "objects": {"cup": {"position": [0.0, 0.0, TABLE_TOP + 0.05]}}
                       if i < 4 else {}} for i in range(8)])
    return str(scene), str(obs)


def test_search_json_prints_one_object_with_regions_plan_and_expected_cost(stream, capsys):
    scene, obs = stream
    code = main(["search", "--scene", scene, "--observations", obs, "--object", "cup", "--particles", "8",
                 "--workers", "0", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    data = json.loads(out)  # exactly one JSON document
    assert {"regions", "plan", "expected_cost"} <= set(data)
    assert math.isclose(sum(r["p"] for r in data["regions"]), 1.0, abs_tol=1e-3)
    assert data["plan"] and 0 < data["plan"][0]["p_find"] <= 1


@pytest.mark.parametrize("extra, message", [
    (["--object", "mug"], r"--object: unknown object 'mug' \(the scene .*s.yaml has: table, cup\)"),
    (["--object", "cup", "--at", "9"], r"--at: 9.0 s is outside the stream .*o.jsonl \(0 s to 0.28 s\)"),
])
def test_search_bad_arguments_are_located_errors(stream, capsys, extra, message):
    scene, obs = stream
    assert main(["search", "--scene", scene, "--observations", obs, "--particles", "4", "--workers", "0", *extra]) == 2
    import re
    assert re.search(message, capsys.readouterr().err)


@pytest.mark.parametrize("text, message", [
    ("viewpoints:\n  - id: a\n    position: [1, 0, 1]\n    target: [0, 0, 0]\n    fov_deg: -5\n",
     r"views.yaml:5: viewpoints\[0\].fov_deg: must be > 0"),
    ("viewpoints:\n  - id: a\n    target: [0, 0, 0]\n", r"views.yaml:2: viewpoints\[0\]: missing field 'position'"),
    ("viewpoints: {a: 1}\n", r"views.yaml:1: viewpoints: must be a list"),
    ("cost: {fixed: 0}\n", r"views.yaml:1: cost.fixed: must be > 0"),
    ("regions:\n  - {name: shelf, min: [0, 0, 1], max: [1, 1, 0]}\n", r"views.yaml:2: regions\[0\].max"),
    ("viewpoints: [\n", r"views.yaml:\d+: invalid YAML"),
    ("zoom: 3\n", r"views.yaml:1: zoom: unknown field"),
])
def test_a_malformed_viewpoint_file_is_a_located_error(tmp_path, stream, capsys, text, message):
    path = tmp_path / "views.yaml"
    path.write_text(text)
    with pytest.raises(ViewpointError, match=message):
        read_viewpoints(str(path))
    scene, obs = stream
    assert main(["search", "--scene", scene, "--observations", obs, "--object", "cup", "--viewpoints", str(path),
                 "--particles", "4", "--workers", "0"]) == 2
    assert "views.yaml" in capsys.readouterr().err


def test_a_viewpoint_file_gives_the_looks_their_cameras_costs_and_regions(tmp_path):
    path = tmp_path / "views.yaml"
    path.write_text("cost: {fixed: 2.0, per_metre: 0.5}\nstart: [2, 0, 1]\nviewpoints:\n"
                    "  - {id: top, position: [0, 0, 2], target: [0, 0, 0.6], up: [1, 0, 0]}\n"
                    "  - {position: [1, 0, 1], orientation: [0, 0, 0, 1]}\n"
                    "regions:\n  - {name: corner, min: [0.2, 0.2, 0.6], max: [0.5, 0.5, 0.9]}\nreplace_regions: true\n")
    vf = read_viewpoints(str(path))
    assert [v.id for v in vf.viewpoints] == ["top", "view1"] and vf.fixed_cost == 2.0 and vf.travel_cost == 0.5
    assert np.allclose(vf.viewpoints[1].camera.target, [1, 0, 2])  # optical z forward: straight up
    assert vf.replace_regions and vf.regions[0].name == "corner" and np.allclose(vf.start, [2, 0, 1])
    with _split_estimator(16, resample_threshold=0.0) as est:
        plan = plan_search(est, "cup", vf)
    assert [n for n, _ in plan.regions] == ["elsewhere"] or plan.regions[0][0] == "corner"
    assert math.isclose(sum(p for _, p in plan.regions), 1.0, abs_tol=1e-12)


def test_ray_tests_skipped_for_segments_clear_of_every_other_box_change_no_answer():
    from physics.visibility import visible_fractions
    views = [FLOOR_VIEW, TABLE_VIEW, Viewpoint("low", CameraSpec(position=(1.2, 0.3, 0.4), target=(-1.0, 0.0, 0.1)))]
    with _split_estimator(16, resample_threshold=0.0) as est:
        ps = ParticleSet.from_estimator(est)
        cup = est.object_ids.index("cup")
        culled = est.pool.look(ps.poses, np.flatnonzero(est.known), np.array([cup]), tuple(v.camera for v in views))
        shard = est.pool._local
        worlds = [pw.world for pw in shard.worlds]
        for w, p in zip(worlds, ps.poses):
            w.set_poses(p)
        plain = np.array([visible_fractions(worlds, shard.camera_for(v.camera), [cup], shard.points, ps.poses[:, [cup]])
                          for v in views])
    assert np.array_equal(culled, plain)
    assert 0 < np.mean(culled > 0) < 1  # some particles seen, some hidden (the table hides the floor from "low")


# -- what the person sees and reaches ----------------------------------------------------------------------

def test_the_person_sees_and_reaches_a_cup_the_robot_cannot_see():
    from physics.scene import scene_from_dict, scene_to_dict

    scene = table_scene(
        {"id": "screen", "static": True, "box": {"size": [0.05, 1.2, 0.6]}, "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.3]}},
        dict(CUP, pose={"position": [-0.3, 0.0, TABLE_TOP + 0.05]}),
        camera={"position": [1.5, 0.0, 1.0], "target": [-0.3, 0.0, 0.7]})
    data = scene_to_dict(scene)
    data["person"] = {"id": "human", "reach": 0.7,
                      "head": {"position": [-1.2, 0.0, 1.5], "target": [-0.3, 0.0, TABLE_TOP]}}
    scene = scene_from_dict(data)
    assert scene_from_dict(scene_to_dict(scene)).person == scene.person
    cfg = EstimatorConfig(particles=8, noise=NoiseConfig(), workers=0)

    def last_belief(hand):
        with SceneEstimator(scene, cfg, np.random.default_rng(0)) as est:
            for i in range(6):
                b = est.update(Frame(0.08 * i, {}, {"human/right": np.array(hand)}))
            cup = est.object_ids.index("cup")
            robot = est.pool.look(est.state.poses, np.flatnonzero(est.known), np.array([cup]), (scene.camera,))
            return b, robot

    belief, robot = last_belief([-0.6, 0.2, 0.9])
    assert np.all(robot == 0)  # the screen hides the cup from the robot's camera in every particle
    person = belief.objects["cup"].person
    assert person == {"id": "human", "p_visible": 1.0, "p_reachable": 1.0}
    assert json.loads(json.dumps(belief.to_json()))["objects"]["cup"]["person"]["p_visible"] == 1.0
    far, _ = last_belief([-2.5, 2.0, 0.9])  # the hand 2.8 m away: out of reach
    assert far.objects["cup"].person["p_reachable"] == 0.0 and far.objects["cup"].person["p_visible"] == 1.0


# -- point guesses and what the person hides ----------------------------------------------------------------

def test_a_look_at_a_point_aims_at_it_and_finds_what_is_there():
    from estimator.applications.search import look_at_point

    with _split_estimator() as est:
        cup = est.object_ids.index("cup")
        point = np.array([0.1, 0.1, TABLE_TOP + 0.05])  # on the table, in plain view from above
        look = look_at_point(est, "cup", point, SearchConfig(), np.random.default_rng(0), label="on table")
        assert np.allclose(look.viewpoint.camera.target, point) and look.regions == ("on table",)
        # every particle has the cup moved to the point, so the look finds it unless the camera misses
        assert look.p_find == pytest.approx(1 - est.config.noise.miss_prob, abs=1e-9)
        assert look.cost >= SearchConfig().fixed_cost
        assert np.all(est.state.poses[:, cup, 2] > 0)  # the estimator's particles are left as they were


def test_a_plan_never_looks_where_it_cannot_find_the_object():
    from estimator.applications.search import person_hides

    with _split_estimator() as est:
        cup = est.object_ids.index("cup")
        # every particle: the cup held by a tracked hand that has been in view 20 updates without it
        est.state.modes[:, cup] = HELD
        est.state.unseen_in_view[:, cup] = 20
        est.memory.hold_hand[cup] = "human/right"
        hides = person_hides(est, cup)
        assert np.all(hides > 0.999)
        plan = plan_search(est, "cup", [FLOOR_VIEW, TABLE_VIEW], rng=np.random.default_rng(0))
        assert plan.looks == [] and plan.p_found == 0.0
        est.state.unseen_in_view[:, cup] = 0  # just lost: hidden with the prior h only
        assert np.allclose(person_hides(est, cup), est.config.noise.hand_occlusion)
