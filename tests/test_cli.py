"""The command line end to end."""
import dataclasses
import json
import re
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
                 "--timeline", str(tl), "--paper"]) == 0
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
    # without --paper: the particle estimator (K = 64), with uncertainty
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--out", str(out), "--workers", "0",
                 "--quiet"]) == 0
    box = json.loads(out.read_text().splitlines()[-1])["objects"]["box"]
    assert np.trace(box["position_cov"]) > 0 and box["mean_position_cov"] == box["position_cov"]  # one mode


def test_bad_frame_is_reported_with_location_or_skipped(files, capsys):
    tmp, scene, obs = files
    rows = stream(10)
    rows[4] = '{"t": 0.2, "objects": {"box": {"position": [0, NaN, 1]}}}'
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--paper"]) == 2
    err = capsys.readouterr().err
    assert f"{obs}:5: objects.box.position[1]: non-finite" in err and "Traceback" not in err
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--skip-bad-frames", "--paper"]) == 0
    assert "1 bad frame(s) skipped" in capsys.readouterr().err


def test_missing_scene_or_urdf_is_a_clear_error(files, capsys):
    tmp, scene, obs = files
    assert main(["run", "--scene", str(tmp / "nope.yaml"), "--observations", str(obs), "--paper"]) == 2
    assert "scene file not found" in capsys.readouterr().err
    scene.write_text(SCENE.replace("table/table.urdf", "table/missing.urdf"))
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--paper"]) == 2
    err = capsys.readouterr().err
    assert "URDF file not found" in err and "objects[0].urdf" in err and ":5:" in err


def test_unknown_object_and_time_going_backwards(files, capsys):
    tmp, scene, obs = files
    rows = stream(6)
    rows[2] = {"t": 0.5, "objects": {"mug": {"position": [0, 0, 1]}}}
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--paper"]) == 2
    assert "unknown object id 'mug'" in capsys.readouterr().err
    rows[2] = {"t": 0.01, "objects": {}}
    rows[3] = {"t": 0.005, "objects": {}}
    write_jsonl(obs, rows)
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--paper"]) == 2
    assert "strictly increasing" in capsys.readouterr().err


def test_demo_runs_without_arguments_with_particles_beside_the_paper(tmp_path):
    res = subprocess.run([sys.executable, "-m", "experiments.cli", "demo", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "Final poses" in res.stdout and "cup" in res.stdout
    cup_block = res.stdout[res.stdout.index("  cup (hidden)"):]
    assert re.search(r"particle estimator \(K = 64\): +isOnTop floor +p=\d\.\d\d", cup_block)
    assert re.search(r"paper's reasoner: +isOnTop floor", cup_block)
    for name in ("estimates.jsonl", "paper_estimates.jsonl"):
        last = json.loads((tmp_path / name).read_text().splitlines()[-1])
        cup = last["objects"]["cup"]
        assert not cup["perceived"] and cup["position"][2] < 0.2  # the hidden cup is on the floor
        assert cup["hypotheses"][0]["support"] == "floor"
    particles = json.loads((tmp_path / "estimates.jsonl").read_text().splitlines()[-1])["objects"]["cup"]
    paper = json.loads((tmp_path / "paper_estimates.jsonl").read_text().splitlines()[-1])["objects"]["cup"]
    assert np.trace(particles["position_cov"]) > 1e-4 and np.trace(paper["position_cov"]) == 0


def test_demo_paper_runs_the_papers_reasoner_alone(capsys):
    assert main(["demo", "--paper"]) == 0
    out = capsys.readouterr().out
    assert "The paper's reasoner (one world, no noise)" in out and "Final poses" in out
    assert "particle estimator" not in out


def _run_args(**kw):
    import argparse
    base = dict(config=None, particles=None, paper=False, workers=None, noise=False, no_noise=False, horizon=None,
                t_perceived=None, d_sim_perc=None, d_perc_prev=None)
    base.update(kw)
    return argparse.Namespace(**base)


def test_run_defaults_to_the_particle_estimator_and_paper_is_asked_for():
    from estimator.config import EstimatorConfig, default_config
    from experiments.cli.common import DEFAULT_PARTICLES, build_config

    default = build_config(_run_args())
    assert DEFAULT_PARTICLES == 64
    assert dataclasses.replace(default, workers=0) == default_config(64) and not default.paper_mode
    assert default.workers >= 1  # one worker per core
    assert build_config(_run_args(paper=True)) == EstimatorConfig.paper()
    assert build_config(_run_args(particles=1)) == EstimatorConfig.paper()
    assert build_config(_run_args(particles=8, no_noise=True)).noise.is_off
    many = build_config(_run_args(particles=8))
    assert many.particles == 8 and not many.noise.is_off and many.workers >= 1 and not many.paper_mode
    with pytest.raises(ValueError, match="--paper"):
        build_config(_run_args(paper=True, particles=8))


def test_a_configuration_file_decides_k_when_the_command_line_does_not(tmp_path):
    from estimator.config import EstimatorConfig
    from experiments.cli.common import build_config

    for text, k in [("noise: {position_std: 0.02}\n", 64), ("particles: 16\n", 16), ("base: paper\n", 1)]:
        (tmp_path / "c.yaml").write_text(text)
        assert build_config(_run_args(config=str(tmp_path / "c.yaml"))).particles == k
    assert build_config(_run_args(config=str(tmp_path / "c.yaml"))) == EstimatorConfig.paper()
    (tmp_path / "c.yaml").write_text("particles: 16\n")
    assert build_config(_run_args(config=str(tmp_path / "c.yaml"), paper=True)) == EstimatorConfig.paper()


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
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            # Ctrl-C as a user's terminal delivers it: an earlier test of the session may
                            # have left SIGINT ignored in this process, which a child would inherit
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
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
