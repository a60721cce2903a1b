"""Rerun recordings: read back with rerun's own reader (entity paths, time points, values), static
scene, particles, two recorders in one process, ``simulate --rerun``; the live view (``run
--rerun-connect`` to a running viewer, ``run --rerun-serve`` opened in a headless browser)."""
import argparse
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections import defaultdict

import numpy as np
import pytest
from rerun.chunk import RrdReader
from scipy.stats import chi2
from scipy.stats import f as f_dist

from estimator.config import EstimatorConfig, NoiseConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.cli.simulate import add_simulate_arguments, run_simulate
from experiments.recording import APPLICATION_ID, Recorder
from experiments.recording_geometry import covariance_ellipsoids
from experiments.recording_options import RecorderOptions
from helpers import TABLE_TOP, frames, headless_chromium, table_scene

pytestmark = pytest.mark.filterwarnings("error::rerun.error_utils.RerunWarning")

CAMERA = {"position": [1.2, 0.0, 1.3], "target": [0.0, 0.0, 0.7]}
BOX = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "mass": 0.2,
       "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.03]}}
BALL = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
        "pose": {"position": [0.2, 0.1, TABLE_TOP + 0.03]}}
TRAY = {"id": "tray", "static": True, "urdf": "pybullet_data://tray/traybox.urdf",
        "pose": {"position": [-0.4, 0.0, TABLE_TOP]}}
K = 6


CUP = {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "mass": 0.1}  # unknown until seen


def _box_path(t):
    """Resting, then lifted into the air from t = 0.5 s (a Pick)."""
    z = TABLE_TOP + 0.035 + max(0.0, t - 0.5) * 0.6
    return {"box": [0.05 * t, 0.0, z]}


def _box_and_cup(t):
    """The box as in :func:`_box_path`; the cup, unknown at first, appears on the table at 0.4 s."""
    out = _box_path(t)
    if t >= 0.4:
        out["cup"] = [0.2, -0.2, TABLE_TOP + 0.045]
    return out


def _run(scene, times, objects_at, path, seed=0, options=None, interleave=None):
    """Estimate ``frames(times, objects_at)`` with K particles, recording every frame and belief."""
    frs = frames(times, objects_at)
    beliefs = []
    with SceneEstimator(scene, EstimatorConfig(particles=K, noise=NoiseConfig()),
                        np.random.default_rng(seed)) as est, Recorder(path, scene, options=options) as rec:
        for f in frs:
            rec.log_frame(f)
            b = est.update(f)
            if b is not None:
                rec.log_belief(b)
                beliefs.append(b)
            if interleave is not None:
                interleave(f)
        timeline = est.timeline.to_json()
        rec.log_timeline(timeline)
    return frs, beliefs, timeline


def read(path):
    """{entity path: {"static": [columns...], "rows": [(t_ns, {component: value})...] sorted by t}}."""
    out = defaultdict(lambda: {"static": [], "rows": []})
    reader = RrdReader(str(path))
    for chunk in reader.stream():
        batch = chunk.to_record_batch()
        cols = {n: batch.column(n).to_pylist() for n in batch.schema.names if n not in ("rerun.controls.RowId", "t")}
        entry = out[chunk.entity_path]
        if chunk.is_static:
            entry["static"].append(cols)
            continue
        assert "t" in batch.schema.names, f"{chunk.entity_path} is not on the t timeline"
        ts = batch.column("t").cast("int64").to_pylist()
        for i, t in enumerate(ts):
            entry["rows"].append((t, {k: v[i] for k, v in cols.items()}))
    for entry in out.values():
        entry["rows"].sort(key=lambda r: r[0])
    return dict(out)


def ns(t):
    return int(round(t * 1e9))


def series(data, entity):
    """Times (ns) and values of a scalar series."""
    rows = data[entity]["rows"]
    return [t for t, _ in rows], [c["Scalars:scalars"][0] for _, c in rows]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    scene = table_scene(BOX, TRAY, CUP, camera=CAMERA)
    frs, beliefs, timeline = _run(scene, np.arange(1, 31) / 30.0, _box_and_cup, path,
                                  options=RecorderOptions(batch=7))
    return path, scene, frs, beliefs, timeline, read(path)


def test_entity_paths_and_time_points(recorded):
    _path, _scene, frs, beliefs, _tl, data = recorded
    assert len(beliefs) >= 8
    expected = {"/world", "/world/scene/table", "/world/scene/tray", "/world/scene/floor", "/world/scene/camera",
                "/world/perceived/objects", "/world/perceived/hands", "/world/belief/consensus",
                "/world/belief/uncertainty", "/world/belief/particles/box", "/world/belief/hypotheses",
                "/world/belief/trajectories", "/plots/ess", "/plots/p_plausible/box", "/plots/p_held/box",
                "/plots/relations/isOnTop/box/table", "/log/timeline", "/log/events"}
    assert expected <= set(data)
    assert not any(p.startswith("/world/truth") for p in data)
    belief_times = [ns(b.t) for b in beliefs]
    for entity in ("/plots/ess", "/plots/p_held/box", "/world/belief/consensus", "/world/belief/particles/box",
                   "/world/belief/trajectories"):
        assert [t for t, _ in data[entity]["rows"]] == belief_times, entity
    assert [t for t, _ in data["/world/perceived/objects"]["rows"]] == [ns(f.t) for f in frs]


def test_one_recording_with_its_own_id_and_a_blueprint(recorded):
    path = recorded[0]
    reader = RrdReader(str(path))
    recs = reader.recordings()
    assert len(recs) == 1 and recs[0].application_id == APPLICATION_ID
    assert len(reader.blueprints()) == 1


def test_scalars_are_the_belief_values(recorded):
    _p, _s, _f, beliefs, _tl, data = recorded
    times, ess = series(data, "/plots/ess")
    assert ess == pytest.approx([b.ess for b in beliefs], rel=1e-12)
    assert len(set(np.round(ess, 6))) > 1  # the ESS does change: the comparison above can fail
    _, held = series(data, "/plots/p_held/box")
    assert held == pytest.approx([b.objects["box"].p_held for b in beliefs], abs=1e-12)
    assert max(held) > 0.5  # the lift was explained by a Pick
    _, on_table = series(data, "/plots/relations/isOnTop/box/table")
    assert on_table == pytest.approx([b.relation_p("box", "isOnTop", "table") for b in beliefs], abs=1e-12)
    assert on_table[0] > 0.5 and on_table[-1] == 0.0  # logged as 0 once no longer listed


def test_consensus_uncertainty_and_particles(recorded):
    _p, _s, _f, beliefs, _tl, data = recorded
    last = beliefs[-1]
    _t, cons = data["/world/belief/consensus"]["rows"][-1]
    assert cons["Boxes3D:labels"] == ["box", "cup"]
    assert np.allclose(cons["Boxes3D:centers"][0], last.objects["box"].position, atol=1e-6)
    assert np.allclose(cons["Boxes3D:half_sizes"], [[0.03, 0.03, 0.03], [0.03, 0.03, 0.04]], atol=1e-6)
    _t, ell = data["/world/belief/uncertainty"]["rows"][-1]
    box = last.objects["box"]
    # the 90 % region of the box's own distribution, a Student-t: with nu dof and covariance C, its
    # squared Mahalanobis distance over C is 3 (nu - 2) / nu times an F(3, nu) variable
    nu = box.position_dof
    assert math.isfinite(nu)
    r = math.sqrt(3 * (nu - 2) / nu * f_dist.ppf(0.9, 3, nu))
    assert abs(r - math.sqrt(chi2.ppf(0.9, 3))) > 0.1  # not the Gaussian's
    half, _q = covariance_ellipsoids(box.position_cov[None], r)
    assert half[0].max() > 1e-3  # the particles do spread
    assert np.allclose(sorted(ell["Ellipsoids3D:half_sizes"][0]), sorted(half[0]), rtol=1e-5, atol=1e-7)
    _t, pts = data["/world/belief/particles/box"]["rows"][-1]
    m = last.object_ids.index("box")
    assert np.allclose(pts["Points3D:positions"], last.particles[:, m, :3], atol=1e-6)
    assert len(pts["Points3D:colors"]) == K
    heaviest = int(np.argmax(last.weights))
    darkest = int(np.argmin([c >> 8 & 0xFFFFFF for c in pts["Points3D:colors"]]))
    assert np.allclose(pts["Points3D:positions"][darkest], last.particles[heaviest, m, :3], atol=1e-6)


def test_objects_appear_when_first_perceived(recorded):
    _p, _s, _f, beliefs, _tl, data = recorded
    labels = [c["Boxes3D:labels"] for _t, c in data["/world/belief/consensus"]["rows"]]
    assert labels == [sorted(b.objects.keys() & {"box", "cup"}, key=["box", "cup"].index) for b in beliefs]
    assert labels[0] == ["box"] and labels[-1] == ["box", "cup"]
    cup_points = [len(c["Points3D:positions"]) for _t, c in data["/world/belief/particles/cup"]["rows"]]
    assert cup_points[0] == 0 and cup_points[-1] == K
    assert len(data["/world/belief/uncertainty"]["rows"][0][1]["Ellipsoids3D:half_sizes"]) == 1


def test_static_scene_is_logged_once_without_time(recorded):
    data = recorded[-1]
    for entity in ("/world/scene/table", "/world/scene/tray", "/world/scene/floor", "/world/scene/camera"):
        assert data[entity]["static"] and not data[entity]["rows"], entity
    (table,) = data["/world/scene/table"]["static"]
    v = np.array(table["Mesh3D:vertex_positions"][0])
    assert v[:, 2].max() == pytest.approx(0.625, abs=2e-3)  # the table top, from the URDF's visual mesh
    assert v[:, 0].min() == pytest.approx(-0.75, abs=2e-3) and v[:, 2].min() == pytest.approx(0.0, abs=2e-3)


def test_timeline_text_log(recorded):
    _p, _s, _f, _b, timeline, data = recorded
    texts = [c["TextLog:text"][0] for _t, c in data["/log/timeline"]["rows"]]
    n_ends = sum(f["end"] is not None for f in timeline["facts"])
    assert len(texts) == len(timeline["facts"]) + n_ends + len(timeline["events"])
    assert any(t.startswith("isHeld(box) begins") for t in texts)
    rows = data["/log/timeline"]["rows"]
    begins = [t for t, c in rows if c["TextLog:text"][0].startswith("isOnTop(box, table) begins")]
    ends = [t for t, c in rows if c["TextLog:text"][0] == "isOnTop(box, table) ends"]
    facts = [f for f in timeline["facts"] if (f["predicate"], f["subject"], f["object"]) == ("isOnTop", "box", "table")]
    assert begins == sorted(ns(f["start"]) for f in facts)
    assert ends == sorted(ns(f["end"]) for f in facts if f["end"] is not None) and ends


def test_heaviest_particles_only_when_capped(tmp_path):
    scene = table_scene(BOX)
    path = tmp_path / "capped.rrd"
    _frs, beliefs, _tl = _run(scene, np.arange(1, 10) / 30.0, _box_path, path,
                              options=RecorderOptions(max_particles_logged=2))
    data = read(path)
    last = beliefs[-1]
    _t, pts = data["/world/belief/particles/box"]["rows"][-1]
    top = np.argsort(-last.weights, kind="stable")[:2]
    m = last.object_ids.index("box")
    assert np.allclose(pts["Points3D:positions"], last.particles[top, m, :3], atol=1e-6)


def test_two_recordings_in_one_process_do_not_mix(tmp_path):
    scene_a = table_scene(BOX)
    scene_b = table_scene(BALL)
    path_a, path_b = tmp_path / "a.rrd", tmp_path / "b.rrd"
    ball_at = lambda t: {"ball": [0.2 - 0.1 * t, 0.1, TABLE_TOP + 0.035]}  # noqa: E731
    times = np.arange(1, 13) / 30.0
    frs_b = frames(times + 5.0, ball_at)  # B's stream runs at other times
    est_b = SceneEstimator(scene_b, EstimatorConfig(particles=K, noise=NoiseConfig()), np.random.default_rng(1))
    beliefs_b = []
    with est_b, Recorder(path_b, scene_b, options=RecorderOptions(batch=3)) as rec_b:
        it = iter(frs_b)

        def step_b(_frame_a):  # one B frame after every A frame: interleaved logging
            f = next(it)
            rec_b.log_frame(f)
            b = est_b.update(f)
            if b is not None:
                rec_b.log_belief(b)
                beliefs_b.append(b)

        _frs_a, beliefs_a, _tl = _run(scene_a, times, _box_path, path_a, interleave=step_b,
                                      options=RecorderOptions(batch=2))
    a, b = read(path_a), read(path_b)
    assert "/plots/p_held/box" in a and "/plots/p_held/ball" in b
    assert not any("ball" in p for p in a) and not any("box" in p for p in b)
    ta, ess_a = series(a, "/plots/ess")
    tb, ess_b = series(b, "/plots/ess")
    assert ta == [ns(x.t) for x in beliefs_a] and tb == [ns(x.t) for x in beliefs_b]
    assert ess_a == pytest.approx([x.ess for x in beliefs_a]) and ess_b == pytest.approx([x.ess for x in beliefs_b])
    ids_a = {r.recording_id for r in RrdReader(str(path_a)).recordings()}
    ids_b = {r.recording_id for r in RrdReader(str(path_b)).recordings()}
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b


def test_truth_rows(tmp_path):
    scene = table_scene(BOX, BALL)
    path = tmp_path / "truth.rrd"
    q = [0.0, 0.0, 0.0, 1.0]
    rows = [{"t": 0.1, "objects": {"box": {"position": [0, 0, 0.66], "orientation": q, "visible": True, "held": False},
                                   "ball": {"position": [0.2, 0, 0.66], "orientation": q, "visible": False,
                                            "held": False}},
             "relations": [{"subject": "box", "predicate": "isOnTop", "object": "table"}], "events": [],
             "hands": {"human/right": [0.3, 0.0, 0.9]}},
            {"t": 0.2, "objects": {"box": {"position": [0, 0, 0.76], "orientation": q, "visible": True, "held": True},
                                   "ball": {"position": [0.2, 0, 0.66], "orientation": q, "visible": False,
                                            "held": False}},
             "relations": [], "events": [{"t": 0.19, "action": "Pick", "subject": "box"}],
             "hands": {"human/right": [0.0, 0.0, 0.8]}}]
    with Recorder(path, scene) as rec:
        for r in rows:
            rec.log_truth(r)
    data = read(path)
    _t, boxes = data["/world/truth/objects"]["rows"][0]
    assert boxes["Boxes3D:labels"] == ["box", "ball (hidden)"]
    assert data["/world/truth/objects"]["rows"][1][1]["Boxes3D:labels"] == ["box (held)", "ball (hidden)"]
    assert series(data, "/plots/truth/held/box") == ([ns(0.1), ns(0.2)], [0.0, 1.0])
    assert series(data, "/plots/truth/relations/isOnTop/box/table")[1] == [1.0, 0.0]
    assert data["/world/truth/hands"]["rows"][1][1]["Points3D:labels"] == ["human/right"]
    (t_ev, ev), = data["/log/truth"]["rows"]
    assert t_ev == ns(0.19) and ev["TextLog:text"] == ["true Pick box"]


def test_closed_recorder_refuses_to_log(tmp_path):
    scene = table_scene(BOX)
    rec = Recorder(tmp_path / "c.rrd", scene)
    rec.close()
    rec.close()
    with pytest.raises(RuntimeError, match="closed"):
        rec.log_frame(frames([0.1], _box_path)[0])


def test_simulate_writes_a_readable_recording(tmp_path):
    parser = argparse.ArgumentParser()
    add_simulate_arguments(parser)
    rrd = tmp_path / "rec" / "truth.rrd"
    args = parser.parse_args(["ball_dropped_into_box", "--duration", "2.0", "--out", str(tmp_path / "sim"),
                              "--rerun", str(rrd), "--quiet"])
    assert run_simulate(args) == 0
    from experiments.simulation.files import read_jsonl

    truth = read_jsonl(tmp_path / "sim" / "truth.jsonl")
    obs = read_jsonl(tmp_path / "sim" / "observations.jsonl")
    data = read(rrd)
    assert [t for t, _ in data["/world/truth/objects"]["rows"]] == [ns(r["t"]) for r in truth]
    assert [t for t, _ in data["/world/perceived/objects"]["rows"]] == [ns(f["t"]) for f in obs]
    assert any(c["TextLog:text"] == ["true Release ball"] for _t, c in data["/log/truth"]["rows"])
    assert "/world/scene/table" in data and not any(p.startswith("/world/belief") for p in data)


# -- the live view: a served stream in a real browser, a running viewer ---------------------------------

RERUN_CLI = [sys.executable, "-m", "rerun_cli"]
LIVE_ENTITIES = {"/world/scene/table", "/world/scene/floor", "/world/perceived/objects", "/world/perceived/hands",
                 "/world/belief/consensus", "/world/belief/uncertainty", "/world/belief/particles/box",
                 "/world/belief/hypotheses", "/plots/ess"}


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _entity_paths(path):
    """Entity paths of a recording (one saved from a stream by rerun's CLI has no footer: fine)."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        return {c.entity_path for c in RrdReader(str(path)).stream()}


def _live_files(tmp_path, n):
    """A scene and an ``n``-frame stream at 30 Hz: the box lifted every 6 s, a tracked hand on it."""
    import yaml

    from estimator.observations import write_observations
    from physics.scene import scene_to_dict
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(scene_to_dict(table_scene(BOX))))

    def at(t):
        z = TABLE_TOP + 0.035 + (0.2 if 3.0 <= t % 6.0 < 4.5 else 0.0)
        return {"box": [0.0, 0.0, z]}

    frs = frames([k / 30 for k in range(n)], at)
    frs = [Frame(f.t, f.objects, {"human/right": f.objects["box"].position + [0, 0, 0.05]}) for f in frs]
    write_observations(str(tmp_path / "obs.jsonl"), frs)
    return scene, tmp_path / "obs.jsonl"


def _stop(proc):
    """End a rerun CLI process (its own session) as Ctrl-C would, so that it closes its file."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)


def test_run_sends_the_recording_to_a_running_viewer(tmp_path):
    """``run --rerun-connect PORT`` beside ``--rerun FILE``: a rerun server that saves what it
    receives gets the entities of the file."""
    scene, obs = _live_files(tmp_path, 60)
    port = _free_port()
    received = tmp_path / "received.rrd"
    server = subprocess.Popen(RERUN_CLI + ["--serve-grpc", "--port", str(port), "--save", str(received)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # until it listens
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.2)
        res = subprocess.run([sys.executable, "-m", "experiments.cli", "run", "--scene", str(scene),
                              "--observations", str(obs), "--rerun", str(tmp_path / "run.rrd"), "--rerun-connect",
                              str(port), "--particles", "4", "--workers", "0", "--quiet"],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        time.sleep(1.0)
    finally:
        _stop(server)
    written = _entity_paths(tmp_path / "run.rrd")
    assert LIVE_ENTITIES <= written and _entity_paths(received) == written


def test_a_bad_live_view_address_or_a_busy_port_is_an_error(tmp_path, capsys):
    from experiments.cli import main

    scene, obs = _live_files(tmp_path, 10)
    assert main(["run", "--scene", str(scene), "--observations", str(obs), "--rerun-connect", "nowhere:port",
                 "--paper"]) == 2
    assert "expected HOST:PORT, PORT or rerun+http://HOST:PORT/proxy" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["run", "--scene", str(scene), "--observations", str(obs), "--rerun-serve", "--rerun-grpc-port",
                     str(port), "--paper"]) == 2
        assert f"cannot listen on 0.0.0.0:{port}" in capsys.readouterr().err


def _pink_pixels(png: bytes) -> int:
    """Pixels of the screenshot drawn in the perceived colour (pink: detections and tracked hands)."""
    import io

    from PIL import Image

    from experiments.recording_draw import PINK

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    return int(np.sum(np.all(np.abs(img - np.array(PINK[:3])) <= 40, axis=-1)))


def test_the_live_view_opens_in_a_headless_browser(tmp_path):
    """``run --rerun-serve`` on a stream replayed at stream time: chromium loads rerun's web viewer
    from the printed address (title, canvas, no error in its console but the web font it cannot
    fetch offline) and draws the perceived box and hand in pink; a rerun client connected to the
    served stream receives the scene's entities (``world/scene/*``, ``world/belief/*``)."""
    driver = headless_chromium()
    if driver is None:
        pytest.skip("chromium and chromedriver are not installed (apt-get install chromium chromium-driver): "
                    "the live view is not opened in a browser")
    scene, obs = _live_files(tmp_path, 3600)  # 2 min at stream time: still running when checked
    web, grpc = _free_port(), _free_port()
    run = subprocess.Popen([sys.executable, "-m", "experiments.cli", "run", "--scene", str(scene), "--observations",
                            str(obs), "--realtime", "--live", "--rerun-serve", str(web), "--rerun-grpc-port",
                            str(grpc), "--particles", "4", "--workers", "0"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    client = None
    try:
        url = None
        for line in run.stderr:
            if line.startswith("live view: open "):
                url = line.split()[3]
                break
        assert url == f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy", url
        client = subprocess.Popen(RERUN_CLI + [f"rerun+http://127.0.0.1:{grpc}/proxy", "--save",
                                               str(tmp_path / "client.rrd")],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        driver.get(url)
        assert driver.title == "Rerun Viewer"
        assert len(driver.find_elements("tag name", "canvas")) == 1
        pink, deadline = 0, time.monotonic() + 60
        while pink < 20 and time.monotonic() < deadline:
            time.sleep(2)
            shot = driver.get_screenshot_as_png()
            pink = _pink_pixels(shot)
        (tmp_path / "viewer.png").write_bytes(shot)
        assert pink >= 20, f"the viewer drew no perceived object: see {tmp_path / 'viewer.png'}"
        # offline, the viewer's own calls out (web font, release check, telemetry, examples) fail, each
        # with a "Failed to fetch" from its code; any other error (a panic, the stream refused) counts
        severe = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        outside = [m for m in severe if "net::ERR_NAME_NOT_RESOLVED" in m and not m.startswith("http://127.0.0.1")]
        fetch = [m for m in severe if "TypeError: Failed to fetch" in m]
        others = [m for m in severe if m not in outside and m not in fetch]
        assert not others and len(fetch) <= len(outside), severe
    finally:
        driver.quit()
        if client is not None:
            _stop(client)
        run.terminate()
        run.wait(60)
    assert LIVE_ENTITIES <= _entity_paths(tmp_path / "client.rrd")
