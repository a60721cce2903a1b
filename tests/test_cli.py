"""The command line end to end."""
import argparse
import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time

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


def test_the_command_line_starts_without_scipy_stats_or_filterpy():
    """Importing the estimator, and building the command line's parser (every subcommand's options),
    imports neither scipy.stats nor filterpy (together a second of start-up): they are imported by
    the subcommands that use them, when they run."""
    code = ("import sys\nimport estimator.filter\nfrom experiments.cli import build_parser\n"
            "build_parser()\n"
            "print(sorted(m for m in ('scipy.stats', 'filterpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


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


# -- streams: standard input and output, pipes, FIFOs, sockets, signals, outputs that are inputs ------

CLI = [sys.executable, "-m", "experiments.cli"]


def _lines(n, lifted=(0.8, 1.4)):
    """``stream(n)`` as JSON lines."""
    return "".join(json.dumps(r) + "\n" for r in stream(n))


def _estimates(text):
    """Estimate lines without the live fields (``merged``, ``latency``)."""
    out = []
    for line in text.splitlines():
        d = json.loads(line)
        d.pop("merged", None)
        d.pop("latency", None)
        out.append(d)
    return out


def _run(*args, **kw):
    kw.setdefault("capture_output", True)
    kw.setdefault("text", True)
    kw.setdefault("timeout", 300)
    return subprocess.run(CLI + ["run", *map(str, args)], **kw)


def test_standard_input_and_output_are_dash(files):
    tmp, scene, obs = files
    ref = tmp / "ref.jsonl"
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--out", str(ref), "--particles", "4",
                 "--workers", "0", "--quiet"]) == 0
    res = _run("--scene", scene, "--observations", "-", "--out", "-", "--timeline", tmp / "t.json",
               "--particles", 4, "--workers", 0, input=obs.read_text())
    assert res.returncode == 0, res.stderr
    assert res.stdout == ref.read_text() and not (tmp / "-").exists()  # the estimates only, on standard output
    assert "Final poses" in res.stderr and json.loads((tmp / "t.json").read_text())["t_end"] is not None
    # the timeline on standard output, the estimates in a file
    res = _run("--scene", scene, "--observations", "-", "--out", tmp / "e.jsonl", "--timeline", "-",
               "--particles", 4, "--workers", 0, "--quiet", input=obs.read_text())
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["version"] == 1 and (tmp / "e.jsonl").read_text() == ref.read_text()


def test_a_malformed_line_on_standard_input_is_located_or_skipped(files):
    tmp, scene, obs = files
    lines = obs.read_text().splitlines()
    lines[2] = '{"t": 0.07, "objects": {"box": {"position": [0, NaN, 1]}}}'
    text = "\n".join(lines) + "\n"
    res = _run("--scene", scene, "--observations", "-", "--out", "-", "--paper", input=text)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "error: <stdin>:3: objects.box.position[1]: non-finite number NaN is not allowed" in res.stderr
    res = _run("--scene", scene, "--observations", "-", "--out", "-", "--paper", "--live", input=text)
    assert res.returncode == 2 and "error: <stdin>:3: objects.box.position[1]: non-finite" in res.stderr  # live too
    res = _run("--scene", scene, "--observations", "-", "--out", "-", "--paper", "--skip-bad-frames", input=text)
    assert res.returncode == 0 and "1 bad frame(s) skipped" in res.stderr
    assert len(res.stdout.splitlines()) == len(_estimates(_run("--scene", scene, "--observations", obs, "--out", "-",
                                                               "--paper", "--quiet").stdout)) == 20


def test_a_closed_output_pipe_ends_the_run_quietly(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    obs = tmp_path / "obs.jsonl"
    write_jsonl(obs, [{"t": round(k / 30, 4), "objects": {"box": {"position": [0.1, 0, TABLE_TOP + 0.04]}}}
                      for k in range(3000)])
    cmd = " ".join(CLI + ["run", "--scene", str(scene), "--observations", str(obs), "--out", "-", "--timeline",
                          str(tmp_path / "t.json"), "--particles", "4", "--workers", "0"])
    res = subprocess.run(["bash", "-c", cmd + ' | head -3; echo "status ${PIPESTATUS[0]}" >&2'],
                         capture_output=True, text=True, timeout=300)
    assert len(res.stdout.splitlines()) == 3 and all(json.loads(x)["objects"] for x in res.stdout.splitlines())
    assert "status 0" in res.stderr and "Traceback" not in res.stderr and "BrokenPipe" not in res.stderr
    assert "the estimates' reader went away" in res.stderr
    timeline = json.loads((tmp_path / "t.json").read_text())  # written, for the frames read
    assert 0.1 <= timeline["t_end"] < 50


def _shm():
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


@pytest.mark.parametrize("signum, status, live", [(signal.SIGTERM, 143, False), (signal.SIGINT, 130, False),
                                                   (signal.SIGTERM, 143, True)])
def test_a_signal_mid_run_writes_the_timeline_and_leaves_nothing_behind(tmp_path, signum, status, live):
    """Two worker processes; the signal comes while the run works (from a file) or waits for frames
    (a live stream on standard input that fell silent)."""
    import psutil

    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    rows = [{"t": round(k / 30, 4), "objects": {"box": {"position": [0.1, 0, TABLE_TOP + 0.04]}}} for k in range(3000)]
    out, tl = tmp_path / "e.jsonl", tmp_path / "t.json"
    shm = _shm()
    src = ["-", "--live"] if live else [tmp_path / "obs.jsonl"]
    if not live:
        write_jsonl(tmp_path / "obs.jsonl", rows)
    proc = subprocess.Popen(CLI + ["run", "--scene", str(scene), "--observations", *map(str, src), "--out", str(out),
                                   "--timeline", str(tl), "--particles", "8", "--workers", "2", "--quiet"],
                            stdin=subprocess.PIPE if live else subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    if live:  # 60 frames, then silence: the run waits for more
        proc.stdin.write("".join(json.dumps(r) + "\n" for r in rows[:60]))
        proc.stdin.flush()
    # live: the 60 frames come in while the workers start; the run catches up with them in one step
    expect = 1 if live else 5
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(out.read_text().splitlines()) < expect):
        time.sleep(0.05)
    children = psutil.Process(proc.pid).children(recursive=True)
    assert len(children) >= 2  # the workers
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert "Traceback" not in err
    lines = out.read_text().splitlines()
    assert len(lines) >= expect and all(json.loads(x)["objects"]["box"] for x in lines)  # every line whole
    last_t = json.loads(lines[-1])["t"]
    assert last_t <= json.loads(tl.read_text())["t_end"] <= last_t + 0.2
    if live:  # it had caught up with the newest frame of the silent stream
        assert last_t == rows[59]["t"] and json.loads(tl.read_text())["t_end"] == last_t
    gone, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, alive
    assert _shm() <= shm  # no shared-memory block left


def test_an_output_that_is_an_input_is_refused_before_anything_is_opened(files):
    tmp, scene, obs = files
    (tmp / "link.jsonl").symlink_to(obs)
    os.link(obs, tmp / "hard.jsonl")
    before = (obs.read_bytes(), os.stat(obs).st_mtime_ns)
    for option, value, field in [("--out", obs, "--out"), ("--out", tmp / "link.jsonl", "--out"),
                                 ("--out", tmp / "hard.jsonl", "--out"), ("--timeline", obs, "--timeline"),
                                 ("--rerun", tmp / "link.jsonl", "--rerun"), ("--out", scene, "--out")]:
        assert main(["run", "--scene", str(scene), "--observations", str(obs), option, str(value), "--paper"]) == 2
        assert (obs.read_bytes(), os.stat(obs).st_mtime_ns) == before
    res = _run("--scene", scene, "--observations", obs, "--out", tmp / "link.jsonl", "--paper")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert f"error: --out: {tmp / 'link.jsonl'} is the same file as --observations {obs}" in res.stderr
    assert (obs.read_bytes(), os.stat(obs).st_mtime_ns) == before and scene.read_text() == SCENE
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--out", "-", "--timeline", "-",
                 "--paper"]) == 2
    assert sorted(p.name for p in tmp.iterdir()) == ["hard.jsonl", "link.jsonl", "obs.jsonl", "scene.yaml"]


def test_existing_outputs_are_replaced_only_once_the_run_has_started(files, capsys):
    tmp, scene, obs = files
    out, tl, rrd = tmp / "e.jsonl", tmp / "t.json", tmp / "r.rrd"
    for p in (out, tl, rrd):
        p.write_text("keep me\n")
    bad = tmp / "bad.jsonl"
    bad.write_text('{"t": 0.0, "objects": {"mug": {"position": [0, 0, 1]}}}\n')
    args = ["--out", str(out), "--timeline", str(tl), "--rerun", str(rrd), "--paper"]
    assert main(["run", "--scene", str(scene), "--observations", str(bad), *args]) == 2  # the first frame is bad
    assert "bad.jsonl:1: objects.mug: unknown object id" in capsys.readouterr().err
    assert [p.read_text() for p in (out, tl, rrd)] == ["keep me\n"] * 3
    assert sorted(p.name for p in tmp.iterdir()) == ["bad.jsonl", "e.jsonl", "obs.jsonl", "r.rrd", "scene.yaml", "t.json"]
    assert main(["run", "--scene", str(scene), "--observations", str(obs), *args, "--quiet"]) == 0
    assert len(out.read_text().splitlines()) == 20 and json.loads(tl.read_text())["version"] == 1
    assert rrd.read_bytes()[:4] == b"RRF2"  # a rerun recording now


def _due_indices(times, horizon=0.08):
    from estimator.config import reasoning_due
    due, last = [], None
    for i, t in enumerate(times):
        if reasoning_due(last, t, horizon):
            due.append(i)
            last = t
    return due


def test_live_through_a_fifo_in_lockstep_is_the_run_without_it(files):
    """The frames come through a FIFO, each time up to the next frame that makes a step due, and
    the next ones only once its estimate is out: a consumer that keeps up merges nothing, and its
    estimates are those of the run without --live (plus merged 0 and a latency)."""
    tmp, scene, obs = files
    ref = _run("--scene", scene, "--observations", obs, "--out", "-", "--particles", 4, "--workers", 0, "--quiet")
    fifo = tmp / "frames.fifo"
    os.mkfifo(fifo)
    proc = subprocess.Popen(CLI + ["run", "--scene", str(scene), "--observations", str(fifo), "--out", "-", "--live",
                                   "--particles", "4", "--workers", "0", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rows = stream()
    got = []
    with open(fifo, "w") as fh:
        start = 0
        for i in _due_indices([r["t"] for r in rows]):
            fh.write("".join(json.dumps(r) + "\n" for r in rows[start:i + 1]))
            fh.flush()
            got.append(proc.stdout.readline())  # the step at frame i: the FIFO holds nothing more
            assert json.loads(got[-1])["t"] == rows[i]["t"]
            start = i + 1
        fh.write("".join(json.dumps(r) + "\n" for r in rows[start:]))
    rest, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    lines = "".join(got) + rest
    assert [json.loads(x)["merged"] for x in lines.splitlines()] == [0] * 20
    assert _estimates(lines) == _estimates(ref.stdout)
    assert all(json.loads(x)["latency"] >= 0 for x in lines.splitlines())


def test_a_live_run_reports_its_particle_count_and_fixed_particles_keeps_it(files):
    """With more particles than the budget's floor (16) a live run may shed them: each estimate line
    says how many it used, within [16, K]; --fixed-particles keeps K (no count in the lines), and
    without --live it is refused."""
    tmp, scene, _ = files
    obs = tmp / "long.jsonl"  # 8 s at twice its speed: steps go on well after the worlds are built
    write_jsonl(obs, [{"t": round(k / 30, 4), "objects": {"box": {"position": [0.1, 0, TABLE_TOP + 0.04]}}}
                      for k in range(240)])
    args = ("--scene", scene, "--observations", obs, "--out", "-", "--particles", 24, "--workers", 0)
    live = _run(*args, "--live", "--realtime", 2)
    assert live.returncode == 0, live.stderr
    ks = [json.loads(x)["particles"] for x in live.stdout.splitlines()]
    assert len(ks) > 1 and all(16 <= k <= 24 for k in ks) and ks[0] == 24
    assert "particles (budget): " in live.stderr
    fixed = _run(*args, "--live", "--fixed-particles")
    assert fixed.returncode == 0 and all("particles" not in json.loads(x) for x in fixed.stdout.splitlines())
    res = _run(*args, "--fixed-particles")
    assert res.returncode == 2 and "--fixed-particles goes with --live" in res.stderr


def test_a_tcp_source_and_a_realtime_replay_give_the_estimates_of_the_file(files):
    import socket
    import threading

    tmp, scene, obs = files
    ref = _run("--scene", scene, "--observations", obs, "--out", "-", "--paper", "--quiet")
    server = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = server.accept()
        with conn:
            conn.sendall(obs.read_bytes())

    threading.Thread(target=serve, daemon=True).start()
    res = _run("--scene", scene, "--observations", f"tcp://127.0.0.1:{server.getsockname()[1]}", "--out", "-",
               "--paper", "--quiet")
    server.close()
    assert res.returncode == 0, res.stderr
    assert res.stdout == ref.stdout
    res = _run("--scene", scene, "--observations", obs, "--out", "-", "--paper", "--quiet", "--realtime", "8")
    assert res.returncode == 0 and res.stdout == ref.stdout  # paced, the same estimates


def test_run_stream_memory_does_not_grow_over_an_endless_standard_input(tmp_path, monkeypatch):
    """``run --observations -`` over a lazily generated stream (the box lifted for 1 s in every 4):
    the project's Python allocations (tracemalloc) between frames 1500 and 2400 grow by less than
    4 kB, where keeping every update time (300 steps) or the whole timeline would add 10 kB or more."""
    import gc
    import threading
    import tracemalloc

    import experiments.cli.run as run_module
    from estimator.config import EstimatorConfig, NoiseConfig

    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    n0, n = 600, 900

    def line(k):
        t = k / 30
        z = TABLE_TOP + 0.04 + (0.25 if 1.0 <= t % 4.0 < 2.0 else 0.0)
        return json.dumps({"t": round(t, 4), "objects": {"box": {"position": [0.1, 0, z]}}}) + "\n"

    r, w = os.pipe()

    def write():
        with os.fdopen(w, "w") as fh:
            for k in range(n0 + 2 * n + 1):
                fh.write(line(k))

    threading.Thread(target=write, daemon=True).start()
    monkeypatch.setattr(sys, "stdin", os.fdopen(r, "r"))
    monkeypatch.setattr(run_module, "TIMES_KEPT", 50)  # bounded, and full before the measurement
    marks, count = {}, [0]

    def on_frame(_):
        count[0] += 1
        if count[0] == n0:
            tracemalloc.start()
        if count[0] in (n0 + n, n0 + 2 * n):
            gc.collect()
            marks[count[0]] = tracemalloc.take_snapshot()

    try:
        summary = run_module.run_stream(str(scene), "-", EstimatorConfig(particles=4, workers=0, noise=NoiseConfig()),
                                        0, None, None, quiet=True, on_frame=on_frame,
                                        stream=run_module.StreamOptions(timeline_window=10.0))
    finally:
        tracemalloc.stop()
    assert summary["frames"] == n0 + 2 * n + 1 and summary["timeline"]["kept_since"] > 60
    project = [tracemalloc.Filter(True, f"*/{d}/*") for d in ("estimator", "experiments", "actions", "physics")]
    a, b = (marks[k].filter_traces(project) for k in (n0 + n, n0 + 2 * n))
    growth = sum(s.size_diff for s in b.compare_to(a, "filename"))
    assert growth < 4096, b.compare_to(a, "lineno")[:5]


def test_run_with_an_adaptive_particle_count_reports_k_per_estimate(files, capsys):
    tmp, scene, obs = files
    out = tmp / "e.jsonl"
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--out", str(out), "--workers", "0",
                 "--particles", "auto", "--min-particles", "8", "--max-particles", "96"]) == 0
    ks = [json.loads(x)["particles"] for x in out.read_text().splitlines()]
    assert ks[0] == 64 and 8 in ks and max(ks) <= 96  # starts at 64; one box seen at rest needs the fewest
    assert re.search(r"particles \(adaptive\): 8 to \d+", capsys.readouterr().out)
    for bad in (["--particles", "many"], ["--particles", "0"]):
        with pytest.raises(SystemExit):
            main(["run", "--scene", str(scene), "--observations", str(obs)] + bad)
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--particles", "32",
                 "--max-particles", "64"]) == 2
    assert "go with --particles auto" in capsys.readouterr().err


@pytest.mark.parametrize("argv, starts", [
    (["run", "--scene", "s.yaml", "--particles", "64"], True),
    (["bench", "--scenario", "all"], True),
    (["ros", "--scene", "s.yaml"], True),
    (["run", "--scene", "s.yaml", "--workers", "0"], False),
    (["run", "--workers=0", "--scene", "s.yaml"], False),
    (["run", "--scene", "s.yaml", "--workers", "2"], True),
    (["simulate", "cluttered_table"], False),
    (["evaluate", "--scenarios", "all"], False),
    ([], False)])
def test_commands_that_build_worlds_in_workers_start_their_fork_server_first(monkeypatch, argv, starts):
    import estimator.worlds.processes as processes
    from experiments.cli import _start_worker_server

    calls = []
    monkeypatch.setattr(processes, "start_worker_server", lambda: calls.append(1))
    _start_worker_server(argv)
    assert calls == ([1] if starts else [])


def test_a_command_imports_its_own_code_and_the_help_lists_every_command():
    code = ("import sys, contextlib, io\n"
            "from experiments.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    main(['config', '--particles', '4', '--json'])\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('experiments.cli.'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert "experiments.cli.run" in out  # config's own module
    assert not {"experiments.cli.search_eval", "experiments.cli.fit", "experiments.cli.evaluate"} & set(out)
    from experiments.cli import COMMANDS, build_parser

    text = subprocess.run([sys.executable, "-m", "experiments.cli", "--help"], capture_output=True, text=True,
                          check=True).stdout
    assert all(name in text for name, *_ in COMMANDS)
    full = build_parser()  # every command with its arguments (the documentation's)
    sub = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == {name for name, *_ in COMMANDS}
    assert all(len(p._actions) > 1 for p in sub.choices.values())  # more than --help each
