"""Scenario files: registry, validation errors located at file/line/field, every built-in scenario
runs and writes well-formed streams, seeded variants."""
import json
import textwrap

import numpy as np
import pytest

from experiments.scenarios import list_scenarios, load_scenario
from experiments.simulation.simulator import sample_variant, simulate, write_outputs
from physics.errors import InputError
from physics.scene import load_scene

PAPER = ["cup_falls_behind_box", "ball_dropped_into_box", "box_emptied_into_box", "ball_in_moving_box",
         "cup_hidden_behind_back"]
OTHERS = ["static_floating", "stacked_tower", "mug_and_tray", "cluttered_table", "cup_carried_behind_box",
          "cup_stashed_behind_screen", "ball_bounces_behind_screen", "ball_rolls_behind_box",
          "stack_pushed_along_table"]

MINIMAL = """\
name: tiny
duration: 1.0
scene:
  camera: {position: [1.1, 0.0, 1.2], target: [0.0, 0.0, 0.65]}
  objects:
    - {id: table, static: true, urdf: "pybullet_data://table/table.urdf", pose: {position: [0, 0, 0]}}
    - {id: cube, box: {size: [0.05, 0.05, 0.05]}, pose: {position: [0.0, 0.0, 0.651]}, mass: 0.1}
hand:
  start: [0.0, 0.3, 1.0]
  script:
    - {t: 0.3, to: {object: cube, offset: [0, 0, 0.06]}, grasp: cube}
    - {t: 0.6, by: [0, 0, 0.1]}
perception: {position_std: 0.002}
randomize:
  objects:
    cube: {position: 0.01, mass: [0.8, 1.2]}
"""


def test_registry_lists_the_builtin_scenarios():
    names = list_scenarios()
    for n in PAPER + OTHERS:
        assert n in names
    for n in names:
        sc = load_scenario(n)
        assert sc.builtin and sc.scene.camera is not None and sc.description
        assert 1.0 <= sc.duration <= 8.0
    assert len(load_scenario("cluttered_table").scene.objects) >= 11  # table + >= 10 objects


def test_unknown_name_lists_available_scenarios():
    with pytest.raises(InputError) as err:
        load_scenario("no_such_scenario")
    assert "cup_falls_behind_box" in str(err.value) and "available" in str(err.value)
    with pytest.raises(InputError, match="not found"):
        load_scenario("some/dir/missing.yaml")


def test_user_file_by_path_runs(tmp_path):
    p = tmp_path / "tiny.yaml"
    p.write_text(MINIMAL)
    sc = load_scenario(str(p))
    assert sc.name == "tiny" and not sc.builtin
    res = simulate(sc, seed=1)
    assert [e["action"] for e in res.events] == ["Pick"]
    assert res.meta["source"] == str(p)


@pytest.mark.parametrize("patch, field, line", [
    (("mass: 0.1}", "mass: -1}"), "scene.objects[1].mass", 7),
    (("grasp: cube}", "grasp: ghost}"), "hand.script[0].grasp", 11),
    (("- {t: 0.6,", "- {t: 0.1,"), "hand.script[1].t", 12),
    (("by: [0, 0, 0.1]}", "by: [0, 0, 0.1], release: cube, jump: 1}"), "hand.script[1].jump", 12),
    (("{position_std: 0.002}", "{position_std: -0.002}"), "perception.position_std", 13),
    (("mass: [0.8, 1.2]}", "mass: [1.2, 0.8]}"), "randomize.objects.cube.mass", 16),
    (("duration: 1.0", "duration: soon"), "duration", 2),
])
def test_bad_files_name_file_line_and_field(tmp_path, patch, field, line):
    p = tmp_path / "bad.yaml"
    p.write_text(MINIMAL.replace(*patch))
    with pytest.raises(InputError) as err:
        load_scenario(str(p))
    e = err.value
    assert e.path == str(p) and e.field == field and e.line == line, str(e)
    assert str(p) in str(e) and field in str(e)


def test_release_without_grasp_and_invalid_yaml(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text(MINIMAL.replace("grasp: cube}", "release: cube}"))
    with pytest.raises(InputError, match="does not hold"):
        load_scenario(str(p))
    p.write_text("duration: [1,\n")
    with pytest.raises(InputError):
        load_scenario(str(p))


def test_grasp_out_of_reach_is_reported(tmp_path):
    p = tmp_path / "far.yaml"
    p.write_text(MINIMAL.replace("offset: [0, 0, 0.06]", "offset: [0, 0, 0.3]"))
    with pytest.raises(InputError, match="away from 'cube'") as err:
        simulate(load_scenario(str(p)), seed=0)
    assert err.value.field == "hand.script[0].grasp"


def test_variants_are_seeded():
    sc = load_scenario("cup_falls_behind_box")
    a, b, c = sample_variant(sc, 0), sample_variant(sc, 0), sample_variant(sc, 1)
    assert a.sampled == b.sampled and a.scene == b.scene and a.script == b.script
    assert a.sampled != c.sampled
    cup0, cup1 = a.scene.get("cup"), c.scene.get("cup")
    assert cup0.position != cup1.position and cup0.mass != cup1.mass and cup0.radius != cup1.radius
    # a resized cup keeps its bottom on the table
    nominal = sc.scene.get("cup")
    assert abs((cup0.position[2] - cup0.height / 2) - (nominal.position[2] - nominal.height / 2)) < 1e-6
    assert [w.t for w in a.script] != [w.t for w in c.script]
    assert all(x.t <= y.t for x, y in zip(a.script, a.script[1:]))


@pytest.mark.parametrize("name", PAPER + OTHERS)
def test_every_scenario_writes_well_formed_streams(name, tmp_path):
    res = simulate(name, seed=0)
    paths = write_outputs(res, tmp_path)
    scene = load_scene(paths["scene.yaml"])
    ids = scene.object_ids
    sc = load_scenario(name)
    assert ids == sc.scene.object_ids
    obs = [json.loads(x) for x in paths["observations.jsonl"].read_text().splitlines()]
    truth = [json.loads(x) for x in paths["truth.jsonl"].read_text().splitlines()]
    meta = json.loads(paths["meta.json"].read_text())
    assert meta["scenario"] == name and meta["seed"] == 0 and meta["format_version"] == 1
    assert len(truth) == round(sc.duration * 30)
    ts = [f["t"] for f in obs]
    assert all(a < b for a, b in zip(ts, ts[1:])) and abs(ts[0] - 1 / 30) < 1e-6
    for f in obs:
        assert list(f) == (["t", "objects", "hands"] if sc.perception.hands_tracked else ["t", "objects"])
        for oid, o in f["objects"].items():
            assert oid in ids and not scene.get(oid).static
            assert len(o["position"]) == 3 and len(o["orientation"]) == 4
            assert abs(np.linalg.norm(o["orientation"]) - 1) < 1e-5
    for f in truth:
        assert set(f["objects"]) == set(ids)
        for o in f["objects"].values():
            assert set(o) == {"position", "orientation", "visible", "visible_fraction", "held"}
        for r in f["relations"]:
            assert r["predicate"] in ("isOnTop", "isIn") and r["subject"] in ids
        for e in f["events"]:
            assert e["action"] in ("Pick", "Place", "Release", "Push") and e["subject"] in ids and e["p"] == 1.0
    # the estimator's scene holds the true settled initial poses
    first = truth[0]["objects"]
    for spec in scene.objects:
        if not spec.static and not first[spec.id]["held"]:
            assert np.allclose(spec.position, first[spec.id]["position"], atol=0.01)
    # every object that the truth says is seen and dynamic shows up in most frames
    seen = sum(len(f["objects"]) for f in obs)
    assert seen > 0
