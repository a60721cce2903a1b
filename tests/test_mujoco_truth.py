"""The MuJoCo ground truth (experiments.simulation.mujoco_truth): the same scenario, another engine."""
import json
import os

import numpy as np
import pybullet_data
import pytest

from experiments.cli import main
from experiments.scenarios import load_scenario
from experiments.simulation.files import read_jsonl, write_outputs
from experiments.simulation.mujoco_model import MAX_RESTITUTION, urdf_centre_of_mass
from experiments.simulation.mujoco_truth import MujocoGroundTruth
from experiments.simulation.simulator import ENGINES, scale_parameters, simulate
from experiments.simulation.variants import sample_variant
from physics.errors import InputError

DATA = pybullet_data.getDataPath()
TABLE_TOP = 0.625


def _relations(frame):
    return sorted((r["subject"], r["predicate"], r["object"]) for r in frame["relations"])


@pytest.fixture(scope="module")
def dropped():
    return {e: simulate("ball_dropped_into_box", 1, engine=e) for e in ENGINES}


def test_a_grasp_and_a_drop_give_the_same_events_and_supports_under_both_engines(dropped):
    bullet, mujoco = dropped["bullet"], dropped["mujoco"]
    assert [(e["action"], e["subject"]) for e in mujoco.events] == [(e["action"], e["subject"]) for e in bullet.events]
    assert "Release" in [e["action"] for e in mujoco.events]
    # the scripted times are the same; the truth's clocks differ (240 Hz and 480 Hz)
    for a, b in zip(bullet.events, mujoco.events):
        assert abs(a["t"] - b["t"]) < 0.01
    assert _relations(mujoco.truth[-1]) == _relations(bullet.truth[-1])
    assert ("ball", "isIn", "box") in _relations(mujoco.truth[-1])
    held = [f["objects"]["ball"]["held"] for f in mujoco.truth]
    assert any(held) and not held[-1]
    # while held, the ball moves with the hand (the weld keeps the grasp's relative pose)
    gaps = [np.linalg.norm(np.subtract(f["objects"]["ball"]["position"], f["hands"]["human/right"]))
            for f in mujoco.truth if f["objects"]["ball"]["held"]]
    assert max(gaps) - min(gaps) < 0.01


def test_the_estimator_is_never_told_which_engine_made_the_truth(dropped, tmp_path):
    bullet, mujoco = dropped["bullet"], dropped["mujoco"]
    assert "engine" not in bullet.meta and mujoco.meta["engine"] == "mujoco"
    assert mujoco.meta["time_step"] == pytest.approx(1 / 480, abs=1e-6)
    write_outputs(mujoco, tmp_path)
    assert "mujoco" not in (tmp_path / "scene.yaml").read_text().lower()
    assert "mujoco" not in (tmp_path / "observations.jsonl").read_text().lower()
    # the same objects, with the nominal parameters: only the settled poses differ
    a = {o.id: o for o in bullet.scene.objects}
    for o in mujoco.scene.objects:
        assert (o.mass, o.friction, o.restitution) == (a[o.id].mass, a[o.id].friction, a[o.id].restitution)


def test_same_seed_same_bytes_under_mujoco(tmp_path):
    for d in ("a", "b"):
        write_outputs(simulate("stack_pushed_along_table", 2, duration=2.0, engine="mujoco"), tmp_path / d)
    for name in ("scene.yaml", "observations.jsonl", "truth.jsonl", "meta.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_a_pushed_box_shoves_the_cup_off_the_table_under_mujoco():
    sim = simulate("cup_falls_behind_box", 0, engine="mujoco")
    assert [(e["action"], e["subject"]) for e in sim.events] == [("Push", "box")]
    end = _relations(sim.truth[-1])
    assert ("cup", "isOnTop", "floor") in end and ("box", "isOnTop", "table") in end


def test_mesh_objects_rest_on_the_table_and_the_mug_ends_in_the_hollow_tray():
    sim = simulate("mesh_clutter_noisy", 0, engine="mujoco")
    first, last = sim.truth[0], sim.truth[-1]
    moved = {e["subject"] for e in sim.events}
    for oid, o in last["objects"].items():
        if oid == "table":
            continue
        # nothing sank into the table or fell through it while settling
        assert min(f["objects"][oid]["position"][2] for f in sim.truth) > TABLE_TOP - 0.01, oid
        if oid not in moved:  # and what nobody touched stays where it settled
            drift = np.linalg.norm(np.subtract(o["position"], first["objects"][oid]["position"]))
            assert drift < 0.005, (oid, drift)
    assert ("mug", "isIn", "tray") in _relations(last)


def test_param_scale_multiplies_the_truths_frictions_and_restitution():
    scenario = load_scenario("ball_bounces_behind_screen")
    base = sample_variant(scenario, 0)
    scaled = scale_parameters(base, 4.0)
    for a, b in zip(base.scene.objects, scaled.scene.objects):
        if a.static:
            assert a == b
            continue
        assert b.friction == pytest.approx(4.0 * (0.5 if a.friction is None else a.friction), rel=1e-5)
        if a.rolling_friction is not None:
            assert b.rolling_friction == pytest.approx(4.0 * a.rolling_friction, rel=1e-5)
        if a.restitution is not None:
            assert b.restitution == pytest.approx(min(4.0 * a.restitution, MAX_RESTITUTION), rel=1e-5)
    assert scale_parameters(base, 1.0) is base
    sim = simulate(scenario, 0, duration=0.5, engine="mujoco", param_scale=2.0)
    assert sim.meta["param_scale"] == 2.0
    nominal = {o.id: o for o in scenario.scene.objects}
    for o in sim.scene.objects:  # the estimator's scene keeps the nominal values
        assert o.friction == nominal[o.id].friction


def test_a_rolling_ball_feels_its_rolling_friction_under_mujoco():
    """Scaled rolling friction stops the ball sooner: the truth's parameters are the physics."""
    ends = []
    for s in (0.5, 4.0):
        sim = simulate("ball_rolls_behind_box", 2, engine="mujoco", param_scale=s)
        p = [f["objects"]["ball"]["position"] for f in sim.truth]
        ends.append(float(np.linalg.norm(np.subtract(p[-1][:2], p[0][:2]))))
    assert ends[1] < ends[0]


def test_bad_engine_or_scale_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(InputError, match="unknown engine 'ode'"):
        simulate("ball_rolls_behind_box", 0, engine="ode")
    with pytest.raises(InputError, match="param_scale: must be a finite number > 0"):
        simulate("ball_rolls_behind_box", 0, param_scale=float("nan"))
    assert main(["simulate", "ball_rolls_behind_box", "--param-scale", "-1", "--out", str(tmp_path), "--quiet"]) == 2
    assert "param_scale: must be a finite number > 0, got -1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["simulate", "ball_rolls_behind_box", "--engine", "ode"])
    assert main(["simulate", "ball_rolls_behind_box", "--engine", "mujoco", "--duration", "0.5",
                 "--out", str(tmp_path / "run"), "--quiet"]) == 0
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["engine"] == "mujoco" and len(read_jsonl(tmp_path / "run" / "truth.jsonl")) == 15


def test_a_urdf_objects_centre_of_mass_is_where_its_urdf_states_it(tmp_path):
    """pybullet_data's duck states its centre of mass 2 cm off the link origin (y): the MuJoCo body
    has it there, scaled with the object, as pybullet does; a URDF without <inertial> states none."""
    duck = os.path.join(DATA, "duck_vhacd.urdf")
    assert np.allclose(urdf_centre_of_mass(duck), [0.0, 0.02, 0.0])
    assert np.allclose(urdf_centre_of_mass(duck, 2.0), [0.0, 0.04, 0.0])
    bare = tmp_path / "bare.urdf"
    bare.write_text('<robot name="b"><link name="l"><collision><geometry><box size="0.1 0.1 0.1"/>'
                    '</geometry></collision></link></robot>')
    assert urdf_centre_of_mass(str(bare)) is None
    variant = sample_variant(load_scenario("cluttered_table"), 0)
    truth = MujocoGroundTruth(variant)
    try:
        i = variant.scene.object_ids.index("duck")
        assert np.allclose(truth.model.body_ipos[truth._bodies[i]], [0.0, 0.02, 0.0])
    finally:
        truth.close()


def test_a_twins_new_mass_mid_run_leaves_every_body_where_it_is():
    """A twin takes new parameters at an object's last sighting (predictability): changing a mass
    mid-run recomputes MuJoCo's constants (mj_setConst, which puts qpos at the model's qpos0); every
    body stays where the run had it, and the new mass is the body's."""
    variant = sample_variant(load_scenario("cluttered_table"), 0)
    truth = MujocoGroundTruth(variant)
    try:
        for _ in range(200):
            truth._step()
        i = variant.scene.object_ids.index("cube")
        before = truth.data.qpos.copy()
        assert not np.allclose(before, truth.model.qpos0)  # the run has moved away from qpos0
        truth.perturb(i, np.zeros(3), {"mass": 0.3})
        assert np.array_equal(truth.data.qpos, before)
        assert truth.model.body_mass[truth._bodies[i]] == pytest.approx(0.3)
    finally:
        truth.close()
