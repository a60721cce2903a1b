"""The command line end to end."""
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from experiments.cli import main

from helpers import TABLE_TOP, write_jsonl

SCENE = f"""\
name: lift
objects:
  - id: table
    static: true
    urdf: pybullet_data://table/table.urdf
    pose: {{position: [0, 0, 0]}}
  - id: box
    box: {{size: [0.06, 0.06, 0.06]}}
    mass: 0.2
    pose: {{position: [0.1, 0, {TABLE_TOP + 0.03}]}}
"""


def stream(n=60):
    rows = []
    for k in range(n):
        t = k / 30
        z = TABLE_TOP + 0.04 + (0.25 if 0.8 <= t < 1.4 else 0.0)
        rows.append({"t": round(t, 4), "objects": {"box": {"position": [0.1, 0, z], "orientation": [0, 0, 0, 1]}}})
    return rows


@pytest.fixture
def files(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    obs = tmp_path / "obs.jsonl"
    write_jsonl(obs, stream())
    return tmp_path, scene, obs


def test_run_writes_estimates_and_timeline(files, capsys):
    tmp, scene, obs = files
    out, tl = tmp / "e.jsonl", tmp / "t.json"
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--out", str(out),
                 "--timeline", str(tl)]) == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) >= 15 and all(set(x) == {"t", "objects", "relations", "events", "ess"} for x in lines)
    box = lines[-1]["objects"]["box"]
    assert set(box) >= {"position", "orientation", "position_cov", "perceived", "p_plausible", "p_held", "hypotheses"}
    assert box["p_plausible"] in (0.0, 1.0) and box["position_cov"] == [[0.0] * 3] * 3
    timeline = json.loads(tl.read_text())
    assert [e["action"] for e in timeline["events"]] == ["Pick", "Place"]
    assert any(f["predicate"] == "isOnTop" and f["end"] is None for f in timeline["facts"])
    printed = capsys.readouterr().out
    assert "Pick" in printed and "Final poses" in printed


def test_bad_frame_is_reported_with_location_or_skipped(files, capsys):
    tmp, scene, obs = files
    rows = stream(10)
    rows[4] = '{"t": 0.2, "objects": {"box": {"position": [0, NaN, 1]}}}'
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs)]) == 2
    err = capsys.readouterr().err
    assert f"{obs}:5: objects.box.position[1]: non-finite" in err and "Traceback" not in err
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--skip-bad-frames"]) == 0
    assert "1 bad frame(s) skipped" in capsys.readouterr().err


def test_missing_scene_or_urdf_is_a_clear_error(files, capsys):
    tmp, scene, obs = files
    assert main(["run", "--scene", str(tmp / "nope.yaml"), "--observations", str(obs)]) == 2
    assert "scene file not found" in capsys.readouterr().err
    scene.write_text(SCENE.replace("table/table.urdf", "table/missing.urdf"))
    assert main(["run", "--scene", str(scene), "--observations", str(obs)]) == 2
    err = capsys.readouterr().err
    assert "URDF file not found" in err and "objects[0].urdf" in err and ":5:" in err


def test_unknown_object_and_time_going_backwards(files, capsys):
    tmp, scene, obs = files
    rows = stream(6)
    rows[2] = {"t": 0.5, "objects": {"mug": {"position": [0, 0, 1]}}}
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs)]) == 2
    assert "unknown object id 'mug'" in capsys.readouterr().err
    rows[2] = {"t": 0.01, "objects": {}}
    rows[3] = {"t": 0.005, "objects": {}}
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs)]) == 2
    assert "strictly increasing" in capsys.readouterr().err


def test_demo_runs_without_arguments(tmp_path):
    res = subprocess.run([sys.executable, "-m", "experiments.cli", "demo", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "Final poses" in res.stdout and "cup" in res.stdout
    last = json.loads((tmp_path / "estimates.jsonl").read_text().splitlines()[-1])
    cup = last["objects"]["cup"]
    assert not cup["perceived"] and cup["position"][2] < 0.2  # the hidden cup is on the floor
    assert cup["hypotheses"][0]["support"] == "floor"


def test_one_particle_without_noise_is_exactly_the_papers_reasoner():
    import argparse
    from estimator.config import EstimatorConfig
    from experiments.cli import build_config

    def args(**kw):
        base = dict(config=None, particles=1, workers=None, noise=False, no_noise=False, horizon=0.08, t_perceived=0.7,
                    d_sim_perc=0.045, d_perc_prev=0.032)
        base.update(kw)
        return argparse.Namespace(**base)

    assert build_config(args()) == EstimatorConfig.paper()
    assert build_config(args(particles=8, no_noise=True)).noise.is_off
    many = build_config(args(particles=8))
    assert not many.noise.is_off and many.workers >= 1 and not many.paper_mode


def test_interrupted_run_keeps_what_it_wrote(tmp_path):
    import signal
    import time

    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    obs = tmp_path / "obs.jsonl"
    rows = [{"t": round(k / 30, 4), "objects": {"box": {"position": [0.1, 0, TABLE_TOP + 0.04]}}} for k in range(3000)]
    write_jsonl(obs, rows)
    out, tl = tmp_path / "e.jsonl", tmp_path / "t.json"
    proc = subprocess.Popen([sys.executable, "-m", "experiments.cli", "run", "--scene", str(scene), "--observations",
                             str(obs), "--out", str(out), "--timeline", str(tl), "--particles", "4", "--workers", "0",
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(out.read_text().splitlines()) < 5):
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    lines = out.read_text().splitlines()
    assert 5 <= len(lines) < 1000 and all(json.loads(x)["objects"]["box"] for x in lines)  # every line whole
    timeline = json.loads(tl.read_text())
    last_t = json.loads(lines[-1])["t"]
    assert last_t <= timeline["t_end"] <= last_t + 0.2  # the interrupt may fall between update and write


def test_config_command_and_run_with_a_configuration_file(files, tmp_path, capsys):
    _, scene, obs = files
    assert main(["config", "--particles", "8", "--workers", "0"]) == 0
    printed = capsys.readouterr().out
    (tmp_path / "all.yaml").write_text(printed)
    from estimator.config import default_config, load_config
    assert load_config(tmp_path / "all.yaml") == dataclasses.replace(default_config(8), workers=0)
    # a file names what it changes; options on the command line win over it
    (tmp_path / "c.yaml").write_text("particles: 4\nworkers: 0\nreasoner: {horizon: 0.1}\nnoise: {position_std: 0.02}\n")
    assert main(["config", "--config", str(tmp_path / "c.yaml"), "--horizon", "0.12", "--json"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert cfg["particles"] == 4 and cfg["workers"] == 0 and cfg["reasoner"]["horizon"] == 0.12
    assert cfg["noise"]["position_std"] == 0.02 and cfg["noise"]["motion_noise"] > 0
    out = tmp_path / "e.jsonl"
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--config", str(tmp_path / "c.yaml"),
                 "--out", str(out), "--quiet"]) == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) > 0 and abs(lines[1]["t"] - lines[0]["t"] - 0.1) < 0.04  # the file's horizon
    (tmp_path / "bad.yaml").write_text("particles: 4\nnoise:\n  position_std: -1\n")
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--config", str(tmp_path / "bad.yaml")]) == 2
    assert f"{tmp_path / 'bad.yaml'}:3: noise.position_std:" in capsys.readouterr().err
