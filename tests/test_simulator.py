"""Ground truth of the scenarios: the truth does what each scenario says, events at the right times,
the hidden objects stay unperceived, latency, and byte-identical files for the same seed."""
import dataclasses
import filecmp
import math

import numpy as np
import pytest

from experiments.cli.simulate import add_simulate_arguments, run_simulate
from experiments.scenarios import load_scenario
from experiments.simulation.ground_truth import GroundTruth
from experiments.simulation.perception import PerceptionConfig
from experiments.simulation.simulator import HAND_ID, sample_variant, simulate
from experiments.simulation.variants import TWIN_PARAMETERS, draw_parameters, twin_variant

SEEDS = range(5)
DT = 1.0 / 240.0


def _relations(frame, subject):
    return {(r["predicate"], r["object"]) for r in frame["relations"] if r["subject"] == subject}


def _perceived(result, oid):
    return sum(oid in f["objects"] for f in result.observations)


def _check_event_frames(result):
    """Each event sits in the first truth frame at or after its time, and only there."""
    listed = []
    prev_t = 0.0
    for f in result.truth:
        for e in f["events"]:
            assert prev_t < e["t"] <= f["t"] + 1e-9
            listed.append(e)
        prev_t = f["t"]
    assert listed == result.events


def _held_intervals(result, oid):
    return [f["t"] for f in result.truth if f["objects"][oid]["held"]]


@pytest.mark.parametrize("seed", SEEDS)
def test_a_cup_falls_behind_box_unseen(seed):
    res = simulate("cup_falls_behind_box", seed)
    first, last = res.truth[0], res.truth[-1]
    assert ("isOnTop", "table") in _relations(first, "cup")
    assert ("isOnTop", "floor") in _relations(last, "cup")
    assert last["objects"]["cup"]["position"][2] < 0.1
    assert not any(f["objects"]["cup"]["visible"] for f in res.truth)
    assert _perceived(res, "cup") == 0
    # the box was pulled (not grasped) towards the far edge and stays on the table
    assert ("isOnTop", "table") in _relations(last, "box")
    assert last["objects"]["box"]["position"][0] < first["objects"]["box"]["position"][0] - 0.2
    assert _perceived(res, "box") > 0.9 * len(res.observations)
    assert not any(o["held"] for f in res.truth for o in f["objects"].values())
    # the box was pushed (one Push, when it started moving under the hand); the cup, shoved off by
    # the box, got nothing
    assert [(e["action"], e["subject"]) for e in res.events] == [("Push", "box")]
    x0 = first["objects"]["box"]["position"][0]
    moved = [f["t"] for f in res.truth if abs(f["objects"]["box"]["position"][0] - x0) > 0.005]
    assert moved and moved[0] - 1 / 30 - DT <= res.events[0]["t"] <= moved[0] + DT
    _check_event_frames(res)


def test_b_ball_released_lands_in_box_out_of_sight():
    res = simulate("ball_dropped_into_box", 0)
    variant = sample_variant(load_scenario("ball_dropped_into_box"), 0)
    t_release = next(w.t for w in variant.script if w.release == "ball")
    assert [(e["action"], e["subject"]) for e in res.events] == [("Release", "ball")]
    assert abs(res.events[0]["t"] - t_release) <= DT + 1e-9
    _check_event_frames(res)
    before = [f for f in res.observations if f["t"] < t_release]
    assert sum("ball" in f["objects"] for f in before) > 0.8 * len(before)  # seen in the hand
    held = _held_intervals(res, "ball")
    assert held and max(held) < t_release
    late = [f for f in res.truth if f["t"] > t_release + 0.5]
    assert late and not any(f["objects"]["ball"]["visible"] for f in late)
    assert ("isIn", "box") in _relations(res.truth[-1], "ball")


@pytest.mark.parametrize("seed", SEEDS)
def test_c_ball_poured_into_blue_box_never_seen(seed):
    res = simulate("box_emptied_into_box", seed)
    variant = sample_variant(load_scenario("box_emptied_into_box"), seed)
    assert ("isIn", "green_box") in _relations(res.truth[0], "ball")
    assert ("isIn", "blue_box") in _relations(res.truth[-1], "ball")
    assert _perceived(res, "ball") == 0
    assert [(e["action"], e["subject"]) for e in res.events] == [("Pick", "green_box"), ("Place", "green_box")]
    grasp_t = next(w.t for w in variant.script if w.grasp == "green_box")
    release_t = next(w.t for w in variant.script if w.release == "green_box")
    assert abs(res.events[0]["t"] - grasp_t) <= DT + 1e-9
    assert abs(res.events[1]["t"] - release_t) <= DT + 1e-9
    _check_event_frames(res)
    held = _held_intervals(res, "green_box")
    assert min(held) >= res.events[0]["t"] and max(held) < res.events[1]["t"]
    assert not any(f["objects"]["ball"]["held"] for f in res.truth)  # carried by the box, not the hand
    # the blue box was not knocked about
    b0, b1 = (np.array(f["objects"]["blue_box"]["position"]) for f in (res.truth[0], res.truth[-1]))
    assert np.linalg.norm(b1 - b0) < 0.02


@pytest.mark.parametrize("seed", SEEDS)
def test_d_ball_stays_in_moving_box(seed):
    res = simulate("ball_in_moving_box", seed)
    assert all(("isIn", "box") in _relations(f, "ball") for f in res.truth)
    p0 = np.array(res.truth[0]["objects"]["box"]["position"])
    path = max(np.linalg.norm(np.array(f["objects"]["box"]["position"]) - p0) for f in res.truth)
    assert path > 0.2
    assert _perceived(res, "ball") == 0
    # the ball, carried inside the held box, gets no event
    assert [(e["action"], e["subject"]) for e in res.events] == [("Pick", "box"), ("Place", "box")]
    _check_event_frames(res)
    # the hand is tracked in every frame, near the box while holding it
    assert all(HAND_ID in f["hands"] for f in res.observations)
    for f in res.truth:
        if f["objects"]["box"]["held"]:
            d = np.subtract(f["hands"][HAND_ID], f["objects"]["box"]["position"])
            assert np.linalg.norm(d) < 0.2


def test_e_cup_held_behind_back_is_hidden_but_held():
    res = simulate("cup_hidden_behind_back", 0)
    hidden_held = [f for f in res.truth if f["objects"]["cup"]["held"] and not f["objects"]["cup"]["visible"]]
    assert len(hidden_held) > 30  # more than a second behind the torso
    for f in hidden_held:
        assert f["objects"]["cup"]["position"][2] > 0.7  # held up, not fallen
    assert all(HAND_ID in f["hands"] for f in res.observations)
    assert [e["action"] for e in res.events] == ["Pick", "Place"]
    assert ("isOnTop", "table") in _relations(res.truth[-1], "cup")
    _check_event_frames(res)


def test_latency_delays_observations():
    sc = load_scenario("ball_in_moving_box")
    cfg = PerceptionConfig(latency_s=0.1)
    res = simulate(dataclasses.replace(sc, perception=cfg), seed=0, duration=3.0)
    lag = 3  # 0.1 s at 30 Hz
    assert len(res.observations) == len(res.truth) - lag + 1  # frames before the latency have no data
    by_t = {f["t"]: f for f in res.truth}
    truth_list = res.truth
    moving = 0
    for obs in res.observations:
        j = next(i for i, f in enumerate(truth_list) if f["t"] == obs["t"])
        past = truth_list[j - lag]["objects"]["box"]["position"] if j >= lag else None
        if "box" in obs["objects"] and past is not None:
            assert np.allclose(obs["objects"]["box"]["position"], past, atol=2e-6)
            now = by_t[obs["t"]]["objects"]["box"]["position"]
            moving += not np.allclose(now, past, atol=1e-3)
    assert moving > 10


def test_frame_rate_is_configurable():
    sc = load_scenario("static_floating")
    res = simulate(dataclasses.replace(sc, perception=PerceptionConfig(rate_hz=10)), seed=0, duration=1.0)
    assert [f["t"] for f in res.observations] == [round(0.1 * k, 6) for k in range(1, 11)]


@pytest.mark.parametrize("name", ["cup_falls_behind_box", "ball_in_moving_box"])
def test_same_seed_gives_byte_identical_files(tmp_path, name):
    import argparse

    parser = argparse.ArgumentParser()
    add_simulate_arguments(parser)
    outs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        assert run_simulate(parser.parse_args([name, "--seed", "2", "--out", str(out), "--quiet",
                                               "--duration", "2.5"])) == 0
        outs.append(out)
    names = ["scene.yaml", "observations.jsonl", "truth.jsonl", "meta.json"]
    match, mismatch, errors = filecmp.cmpfiles(outs[0], outs[1], names, shallow=False)
    assert match == names and not mismatch and not errors
    other = tmp_path / "other"
    assert run_simulate(parser.parse_args([name, "--seed", "3", "--out", str(other), "--quiet",
                                           "--duration", "2.5"])) == 0
    assert (other / "truth.jsonl").read_bytes() != (outs[0] / "truth.jsonl").read_bytes()


def test_cli_list_and_errors(capsys):
    import argparse

    parser = argparse.ArgumentParser()
    add_simulate_arguments(parser)
    assert run_simulate(parser.parse_args(["--list"])) == 0
    out = capsys.readouterr().out
    assert "cup_falls_behind_box" in out and "(a)" in out
    assert run_simulate(parser.parse_args([])) == 2
    assert run_simulate(parser.parse_args(["nope"])) == 2
    assert "available" in capsys.readouterr().err


def test_demo_files_are_shipped_and_consistent():
    from pathlib import Path

    from physics.scene import load_scene

    data = Path(__file__).resolve().parents[1] / "experiments" / "data"
    scene = load_scene(data / "demo_scene.yaml")
    assert {"table", "box", "cup"} == set(scene.object_ids)
    sizes = sum((data / n).stat().st_size for n in ("demo_scene.yaml", "demo_observations.jsonl",
                                                     "demo_truth.jsonl"))
    assert sizes < 250_000
    res = simulate("cup_falls_behind_box", 0)
    import json

    lines = (data / "demo_observations.jsonl").read_text().splitlines()
    assert [json.loads(x) for x in lines] == res.observations, (
        "demo files are stale: regenerate with `python -m experiments.cli.simulate cup_falls_behind_box "
        "--seed 0 --out /tmp/demo` and copy scene.yaml / observations.jsonl / truth.jsonl / meta.json "
        "to experiments/data/demo_*")
    assert math.isclose(json.loads(lines[-1])["t"], res.observations[-1]["t"])


def _push_scenario(obj: dict, hand_z: float, contents: list | None = None):
    """A box (or container) on the table at x = 0, and a hand that comes from +x with ``collide: true``
    and pushes it 20 cm towards -x along the table, then leaves."""
    from experiments.scenarios.parsing import scenario_from_dict

    return scenario_from_dict({
        "name": "push_test", "duration": 3.0,
        "scene": {"objects": [{"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
                               "pose": {"position": [0, 0, 0]}}, obj, *(contents or [])]},
        "hand": {"start": [0.3, 0.0, hand_z], "collide": True, "script": [
            {"t": 0.6, "to": [0.14, 0.0, hand_z]},
            {"t": 1.8, "by": [-0.2, 0.0, 0.0]},
            {"t": 2.1, "by": [0.05, 0.0, 0.0], "collide": False},
            {"t": 2.5, "by": [0.1, 0.0, 0.2]}]}})


def test_a_box_pushed_along_the_table_is_one_push_and_no_pick_or_place():
    box = {"id": "box", "box": {"size": [0.1, 0.1, 0.1]}, "mass": 0.3, "friction": 0.5,
           "pose": {"position": [0.0, 0.0, 0.676]}}
    res = simulate(_push_scenario(box, 0.68), 0)
    assert [(e["action"], e["subject"]) for e in res.events] == [("Push", "box")]
    _check_event_frames(res)
    x = np.array([f["objects"]["box"]["position"][0] for f in res.truth])
    t = np.array([f["t"] for f in res.truth])
    assert x[-1] < x[0] - 0.1  # really pushed
    started = t[np.argmax(np.abs(x - x[0]) > 0.005)]  # the first frame it had moved
    assert started - 1 / 30 - DT <= res.events[0]["t"] <= started + DT
    assert not any(f["objects"]["box"]["held"] for f in res.truth)
    assert ("isOnTop", "table") in _relations(res.truth[-1], "box")


def test_the_contents_of_a_pushed_container_get_no_event():
    crate = {"id": "crate", "container": {"size": [0.2, 0.2, 0.12], "wall": 0.01}, "mass": 0.5, "friction": 0.5,
             "pose": {"position": [-0.05, 0.0, 0.686]}}
    ball = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05, "pose": {"position": [-0.05, 0.0, 0.666]}}
    res = simulate(_push_scenario(crate, 0.70, [ball]), 0)
    b0, b1 = (np.array(f["objects"]["ball"]["position"]) for f in (res.truth[0], res.truth[-1]))
    assert np.linalg.norm(b1[:2] - b0[:2]) > 0.05  # the ball went with its crate...
    assert all(("isIn", "crate") in _relations(f, "ball") for f in res.truth)
    assert [(e["action"], e["subject"]) for e in res.events] == [("Push", "crate")]  # ...and has no event


def test_a_box_knocked_off_the_table_is_no_push():
    # the hand sweeps a light box off the table edge: it falls, it was not pushed along its support
    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "mass": 0.1,
           "pose": {"position": [-0.6, 0.0, 0.656]}}
    from experiments.scenarios.parsing import scenario_from_dict

    sc = scenario_from_dict({
        "name": "knock", "duration": 2.5,
        "scene": {"objects": [{"id": "table", "static": True, "urdf": "pybullet_data://table/table.urdf",
                               "pose": {"position": [0, 0, 0]}}, box]},
        "hand": {"start": [-0.3, 0.0, 0.66], "collide": True, "script": [
            {"t": 1.0, "to": [-1.1, 0.0, 0.66]}]}})
    res = simulate(sc, 0)
    assert res.truth[-1]["objects"]["box"]["position"][2] < 0.1  # on the floor
    assert res.events == []


def test_a_twin_moves_dynamic_objects_horizontally_and_scales_their_parameters_within_bounds():
    variant = sample_variant(load_scenario("ball_bounces_behind_screen"), 3)
    std, scale = 0.001, 0.01
    twins = [twin_variant(variant, np.random.default_rng(k), std, scale) for k in range(200)]
    offsets = []
    for twin in twins:
        assert twin.script == variant.script
        for a, b in zip(variant.scene.objects, twin.scene.objects):
            if a.static:
                assert a == b
                continue
            assert b.position[2] == a.position[2]  # horizontally only
            offsets.append(np.subtract(b.position[:2], a.position[:2]))
            for key in TWIN_PARAMETERS:
                va, vb = getattr(a, key), getattr(b, key)
                if va is None:
                    assert vb is None
                else:
                    assert abs(vb / va - 1.0) <= scale + 1e-12
    offsets = np.array(offsets).ravel()
    n = offsets.size
    # the offsets are N(0, std^2): mean within 4 standard errors of 0, variance within a chi-square band
    assert abs(offsets.mean()) < 4 * std / math.sqrt(n)
    var_ratio = offsets.var() / std ** 2
    assert 1 - 4 * math.sqrt(2 / n) < var_ratio < 1 + 4 * math.sqrt(2 / n)
    # the same generator state gives the same twin; none at zero size is the variant itself
    assert twin_variant(variant, np.random.default_rng(5), std, scale) == twin_variant(
        variant, np.random.default_rng(5), std, scale)
    assert twin_variant(variant, np.random.default_rng(5), 0.0, 0.0).scene == variant.scene


def test_parameters_drawn_again_are_uniform_in_the_scenarios_ranges():
    """ball_bounces_behind_screen randomises the ball's mass factor in [0.8, 1.2] and its restitution
    in [0.3, 0.8], and the bin's position only: 400 draws for seed 3's variant put the ball's
    restitution uniformly in its range (mean within 4 standard errors of 0.55, every draw inside) and
    its mass at the nominal 0.05 kg times a factor in range; nothing else is drawn."""
    variant = sample_variant(load_scenario("ball_bounces_behind_screen"), 3)
    rng = np.random.default_rng(7)
    draws = [draw_parameters(variant, rng) for _ in range(400)]
    assert all(set(d) == {"bin", "ball"} and d["bin"] == {} and set(d["ball"]) == {"mass", "restitution"}
               for d in draws)
    rest = np.array([d["ball"]["restitution"] for d in draws])
    mass = np.array([d["ball"]["mass"] for d in draws])
    assert np.all((rest >= 0.3) & (rest <= 0.8)) and np.all((mass >= 0.04 - 1e-12) & (mass <= 0.06 + 1e-12))
    se = 0.5 / math.sqrt(12) / math.sqrt(len(rest))
    assert abs(rest.mean() - 0.55) < 4 * se
    assert len(set(rest.tolist())) == len(rest)  # drawn afresh each time
    assert draw_parameters(variant, np.random.default_rng(1)) == draw_parameters(variant, np.random.default_rng(1))


def test_a_perturbation_can_change_an_objects_parameters_from_then_on():
    """ball_rolls_behind_box seed 13: the flicked ball rolls along the table (to its far edge);
    given twenty times its rolling friction 0.4 s after the flick, it covers less than half the
    distance in the next 0.6 s, and until then the run is the truth's."""
    variant = sample_variant(load_scenario("ball_rolls_behind_box"), 13)
    ball = variant.scene.index("ball")
    with GroundTruth(variant) as gt:
        base = gt.run(1.8, np.random.default_rng(0))
        step = int(round(1.2 / gt.dt))
    friction = variant.scene.objects[ball].rolling_friction
    with GroundTruth(variant) as gt:
        slowed = gt.run(1.8, np.random.default_rng(0), {step: [(ball, np.zeros(3), {"rolling_friction": 20 * friction})]})
        assert gt.world.get_dynamics(ball)["rolling_friction"] == pytest.approx(20 * friction)
    at = [r for r in base.truth if r["t"] <= 1.2 - 1e-9]
    assert [r["objects"]["ball"]["position"] for r in at] == [r["objects"]["ball"]["position"] for r in slowed.truth[:len(at)]]

    def travel(res):
        return abs(res.truth[-1]["objects"]["ball"]["position"][0] - at[-1]["objects"]["ball"]["position"][0])

    assert travel(slowed) < 0.5 * travel(base)


@pytest.mark.parametrize("kwargs", [dict(position_std=-0.001, param_scale=0.01),
                                    dict(position_std=math.nan, param_scale=0.01),
                                    dict(position_std=0.001, param_scale=1.0)])
def test_bad_twin_sizes_are_refused(kwargs):
    variant = sample_variant(load_scenario("static_floating"), 0)
    with pytest.raises(ValueError):
        twin_variant(variant, np.random.default_rng(0), **kwargs)


def test_a_perturbation_moves_a_free_object_or_the_hand_that_holds_one():
    """GroundTruth.perturb: a free object is moved, its velocity kept; an object in the hand is not
    moved itself, the hand's path is shifted, and the object follows it: the ball that the hand of
    ball_dropped_into_box carries is 2 cm further along x just before it is let go."""
    scenario = load_scenario("ball_dropped_into_box")
    variant = sample_variant(scenario, 0)
    ball = variant.scene.index("ball")
    release = next(w.t for w in variant.script if w.release == "ball")

    def run(perturbations):
        with GroundTruth(variant) as gt:
            truth = gt.run(release - 0.05, np.random.default_rng([0, 1]), perturbations).truth
            return np.array(truth[-1]["objects"]["ball"]["position"]), gt.dt, gt.hand_shift

    base, dt, shift = run(None)
    assert np.all(shift == 0)
    moved, _dt, shift = run({int(round(0.5 / dt)): [(ball, np.array([0.02, 0.0, 0.0]), None)]})
    assert np.allclose(shift, [0.02, 0.0, 0.0])
    assert moved[0] - base[0] == pytest.approx(0.02, abs=0.003) and abs(moved[1] - base[1]) < 0.003
    with GroundTruth(variant) as gt:  # free: the object itself moves, at once
        gt.settle()
        box = variant.scene.index("box")
        before = gt.world.get_poses([box])[0, :3]
        gt.perturb(box, [0.01, -0.02, 0.0])
        assert np.allclose(gt.world.get_poses([box])[0, :3] - before, [0.01, -0.02, 0.0], atol=1e-9)
