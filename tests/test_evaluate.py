"""Trials, scoring, sweeps, resumption, backends and the report of experiments.evaluation (small, short
sweeps)."""
from __future__ import annotations

import csv
import json
import math
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from experiments.cli import evaluate as evaluate_cli
from experiments.evaluation.method_steps import MethodRun, StepEstimate
from experiments.evaluation.metrics import truth_supports
from experiments.evaluation.report import markdown_event_section, pooled_event_counts
from experiments.evaluation.scoring import score_run
from experiments.evaluation.significance import paired_tests
from experiments.evaluation.summary import summarize
from experiments.evaluation.sweep import SweepConfig, read_rows, run_sweep
from experiments.evaluation.trials import TrialSpec, deterministic_part, run_trial, trial_rng
from experiments.simulation.simulator import simulate

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("ball_dropped_into_box", "cup_falls_behind_box")
SEEDS = (0, 1, 2)
METHODS = ("last-seen", "paper", "particles")
K = 4
DURATION = 2.0
SMALL = SweepConfig(SCENARIOS, SEEDS, METHODS, (K,), DURATION)
SUBSET = SweepConfig(SCENARIOS[1:], SEEDS[:2], METHODS, (K,), DURATION)
"""A part of SMALL for the backend comparisons (its rows are a subset of the reference's)."""
CLI_ARGS = ["--scenarios", ",".join(SCENARIOS), "--seeds", str(len(SEEDS)), "--methods", ",".join(METHODS),
            "--particles", str(K), "--duration", str(DURATION), "--workers", "1", "--quiet"]


def _rows_without_timing(rows):
    return sorted((deterministic_part(r) for r in rows), key=lambda r: r["key"])


def _summary_without_timing(path):
    with open(path, newline="") as fh:
        return [{k: v for k, v in rec.items() if not k.startswith("timing.")} for rec in csv.DictReader(fh)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The small sweep, uninterrupted, in this process: its rows and its folder."""
    out = tmp_path_factory.mktemp("reference")
    rows = run_sweep(SMALL, out, workers=1, progress=False)
    return rows, out


# -- scoring -----------------------------------------------------------------------------------------
def _oracle(sim) -> MethodRun:
    """A perfect method: the truth itself, at every third frame."""
    ids = list(sim.scene.object_ids)
    steps = []
    for row in sim.truth[::3]:
        objs = row["objects"]
        pos = np.array([objs[o]["position"] for o in ids])
        held = np.array([objs[o]["held"] for o in ids])
        rels = {(r["subject"], r["predicate"], r["object"]): 1.0 for r in row["relations"]}
        top = [sorted(truth_supports(row["relations"], o, bool(objs[o]["held"])), key=str)[0] for o in ids]
        steps.append(StepEstimate(row["t"], pos, np.zeros((len(ids), 3, 3)), (~held).astype(float),
                                  held.astype(float), top, rels))
    return MethodRun(steps, [dict(e) for e in sim.events], [0.0] * len(steps), 1)


def test_a_perfect_estimate_scores_zero_error_and_f1_one():
    sim = simulate("ball_dropped_into_box", 0, duration=2.5)
    s = score_run(sim.scene, sim.truth, sim.events, _oracle(sim))
    assert s["n_hidden"] > 0 and s["events_true"] >= 1
    for f in ("err_median", "err_p90", "err_hidden_median", "err_hidden_p90", "err_end_mean", "err_end_max"):
        assert s[f] == 0.0, f
    assert s["success_end"] == 1.0 and s["success_end_hidden"] == 1.0
    assert s["ontop_f1"] == 1.0 and s["ontop_acc"] == 1.0
    assert s["isin_f1"] == 1.0 and s["isin_acc"] == 1.0  # the ball ends in the box
    assert s["event_f1"] == 1.0 and s["event_precision"] == 1.0 and s["event_recall"] == 1.0
    assert s["event_latency"] == 0.0
    assert s["release_f1"] == 1.0 and s["release_latency"] == 0.0 and s["release_true"] == s["release_matched"] == 1
    assert math.isnan(s["push_f1"]) and s["push_true"] == 0 and s["pick_est"] == 0  # none in this scenario
    for f in ("brier_plausible", "ece_plausible", "brier_isin", "ece_isin", "brier_isontop", "ece_isontop"):
        assert s[f] == 0.0, f
    assert s["cover50_hidden"] == 1.0 and s["cover90_hidden"] == 1.0
    # the hidden samples split into the first second of each occlusion and the rest
    assert s["n_hidden_early"] > 0 and s["n_hidden_early"] + s["n_hidden_late"] == s["n_hidden"]
    assert s["err_hidden_early_median"] == 0.0 and s["cover90_hidden_early"] == 1.0


def test_a_point_estimate_off_by_ten_cm_is_scored_as_such():
    sim = simulate("cup_falls_behind_box", 0, duration=1.0)
    run = _oracle(sim)
    for s in run.steps:
        s.positions = s.positions + np.array([0.0, 0.1, 0.0])
    s = score_run(sim.scene, sim.truth, sim.events, run)
    assert s["err_median"] == pytest.approx(0.1) and s["err_end_max"] == pytest.approx(0.1)
    assert s["success_end"] == 0.0
    assert s["cover90"] == 0.0  # 10 cm is 20 floor standard deviations away


def test_trial_rng_depends_on_seed_and_method_only():
    a = trial_rng(3, "particles").random(4)
    assert np.array_equal(a, trial_rng(3, "particles").random(4))
    assert not np.array_equal(a, trial_rng(3, "paper").random(4))
    assert not np.array_equal(a, trial_rng(4, "particles").random(4))


def test_a_trial_row_is_flat_json_and_reproducible():
    spec = TrialSpec("cup_falls_behind_box", 1, "particles", K, 1.5, trace=True)
    a, b = run_trial(spec), run_trial(spec)
    assert deterministic_part(a["row"]) == deterministic_part(b["row"])
    row = json.loads(json.dumps(a["row"], allow_nan=False))
    assert row["key"] == spec.key == "cup_falls_behind_box__s1__particles__K4__1.5s"
    assert set(row["timing"]) >= {"update_ms_median", "update_ms_p95", "peak_rss_mb", "trial_s"}
    assert row["timing"]["peak_rss_mb"] > 0
    assert set(row["reliability"]) == {"plausible", "isIn", "isOnTop"}
    trace = a["trace"]
    assert len(trace["cloud"]) == K and len(trace["t"]) == row["n_steps"]


# -- the results file ---------------------------------------------------------------------------------
def test_read_rows_drops_and_repairs_a_truncated_last_line(tmp_path):
    p = tmp_path / "trials.jsonl"
    p.write_text('{"key": "a", "x": 1}\n{"key": "b", "x": 2}\n{"key": "c", "x"')
    rows = read_rows(p, repair=True)
    assert [r["key"] for r in rows] == ["a", "b"]
    assert p.read_text() == '{"key": "a", "x": 1}\n{"key": "b", "x": 2}\n'
    p.write_text('{"key": "a", "x": 1}\n{"key": "a", "x": 3}')  # complete line without newline
    assert read_rows(p, repair=True) == [{"key": "a", "x": 3}]
    assert p.read_text().endswith("}\n")
    p.write_text('{"key": "a"}\nnot json\n{"key": "b"}\n')
    with pytest.raises(ValueError, match="line 2"):
        read_rows(p)


def test_sweep_writes_rows_summary_and_figures(reference):
    rows, out = reference
    assert len(rows) == len(SCENARIOS) * len(SEEDS) * len(METHODS)
    lines = (out / "trials.jsonl").read_text().splitlines()
    assert len(lines) == len(rows) and {json.loads(x)["key"] for x in lines} == {r["key"] for r in rows}
    for name in ("summary.md", "summary.csv", "tests.csv", "reliability.png", "update_time.png", "metrics.png",
                 *(f"views_{s}.png" for s in SCENARIOS), *(f"error_{s}.png" for s in SCENARIOS)):
        assert (out / name).stat().st_size > 0, name
    md = (out / "summary.md").read_text()
    assert "| all scenarios | particles (K=4) |" in md and "Wilcoxon" in md
    assert "| particles (K=4) | Push |" in md  # the events by action, pooled
    assert all(k in rows[0] for k in ("push_f1", "push_precision", "push_recall", "push_latency", "pick_true"))
    summary = summarize(rows)
    assert {(r["scenario"], r["method"]) for r in summary} >= {(s, m) for s in SCENARIOS for m in METHODS}
    tests = paired_tests(rows)
    assert {t["scenario"] for t in tests} == set(SCENARIOS) | {"all scenarios"}
    assert all(t["err_end_mean.n"] == len(SEEDS) for t in tests if t["scenario"] != "all scenarios")


def test_a_rerun_with_everything_done_runs_nothing(reference, tmp_path, capsys):
    rows, out = reference
    shutil.copy(out / "trials.jsonl", tmp_path / "trials.jsonl")
    # as if another version of the code had written them: the user is told they are kept
    (tmp_path / "runs.jsonl").write_text(json.dumps({"commit": "0" * 40, "dirty": False}) + "\n")
    before = (tmp_path / "trials.jsonl").read_bytes()
    again = run_sweep(SMALL, tmp_path, workers=1, progress=False, report=False,
                      on_row=lambda r: pytest.fail("a finished trial ran again"))
    assert (tmp_path / "trials.jsonl").read_bytes() == before
    assert _rows_without_timing(again) == _rows_without_timing(rows)
    err = capsys.readouterr().err
    assert f"{len(rows)} of {len(rows)} trials are kept" in err and "0000000000" in err


# -- interruption --------------------------------------------------------------------------------------
def test_a_sweep_killed_half_way_and_rerun_gives_the_same_table(reference, tmp_path):
    rows, ref_out = reference
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "experiments.cli.evaluate", *CLI_ARGS, "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    path = out / "trials.jsonl"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if path.exists() and path.read_text().count("\n") >= 3:
                break
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    n_before = path.read_text().count("\n")
    assert 3 <= n_before < len(rows), "the sweep was not interrupted half-way"
    with open(path, "a") as fh:  # and as if killed in the middle of writing a line
        fh.write('{"key": "ball_dropped_into_box__s2__paper__K1__2s", "version": 1, "scen')
    assert evaluate_cli.main([*CLI_ARGS, "--out", str(out)]) == 0
    lines = path.read_text().splitlines()
    assert len(lines) == len(rows) and all(json.loads(x) for x in lines)
    assert _rows_without_timing(read_rows(path)) == _rows_without_timing(rows)
    assert _summary_without_timing(out / "summary.csv") == _summary_without_timing(ref_out / "summary.csv")


def _state_and_parent(pid_dir: Path) -> tuple[str, int] | None:
    """A process's state letter and parent pid from ``/proc/<pid>/stat`` (None: gone)."""
    try:
        stat = (pid_dir / "stat").read_text()
    except OSError:
        return None
    state, ppid = stat[stat.rindex(")") + 2:].split()[:2]
    return state, int(ppid)


def _alive(pid: int) -> bool:
    found = _state_and_parent(Path(f"/proc/{pid}"))
    return found is not None and found[0] != "Z"


def _children(pid: int) -> dict[int, str]:
    """The processes whose parent is ``pid`` and that are not zombies: ``{pid: command line}`` (Linux)."""
    out = {}
    for d in Path("/proc").iterdir():
        found = _state_and_parent(d) if d.name.isdigit() else None
        if found is not None and found[1] == pid and found[0] != "Z":
            try:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_the_pool_workers_of_a_killed_sweep_end_with_it(tmp_path, sig):
    """``evaluate --workers 2`` killed: its spawned trial workers end too instead of running on,
    orphaned, through the trials they had queued; the trials written are kept. SIGKILL: no handler
    runs and no pool is closed, the workers notice their parent is gone (``exit_with_parent``).
    SIGTERM (``kill``, systemd, a batch scheduler): the run ends as Ctrl-C ends it, saying so, exit
    status 143, and the trials running are ended rather than waited for."""
    out = tmp_path / "killed"
    args = [*CLI_ARGS, "--out", str(out)]
    args[args.index("--workers") + 1] = "2"
    proc = subprocess.Popen([sys.executable, "-m", "experiments.cli.evaluate", *args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    path, workers = out / "trials.jsonl", {}
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            workers = {p: c for p, c in _children(proc.pid).items() if "multiprocessing.spawn" in c}
            if len(workers) == 2 and path.exists() and path.read_text().count("\n") >= 1:
                break
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)  # a liveness bound, not a speed one
    finally:
        proc.kill()
        proc.wait()
    assert len(workers) == 2, "the sweep's two workers were not seen running"
    if sig == signal.SIGTERM:
        assert proc.returncode == 143, err
        assert "terminated (SIGTERM): finished trials are kept in" in err and "Traceback" not in err
    deadline = time.monotonic() + 60  # a liveness bound (the workers check every PARENT_POLL s), not a speed one
    while time.monotonic() < deadline and any(_alive(p) for p in workers):
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers), "orphaned trial workers are still running"
    lines = path.read_text().splitlines()
    assert lines and all(json.loads(x)["key"] for x in lines[:-1])


def test_a_sweep_resumed_from_a_truncated_file_gives_the_same_table(reference, tmp_path):
    rows, ref_out = reference
    data = (ref_out / "trials.jsonl").read_text().splitlines(keepends=True)
    (tmp_path / "trials.jsonl").write_text("".join(data[:7]) + data[7][: len(data[7]) // 2])
    ran = []
    run_sweep(SMALL, tmp_path, workers=1, progress=False, on_row=ran.append)
    assert len(ran) == len(rows) - 7
    assert _summary_without_timing(tmp_path / "summary.csv") == _summary_without_timing(ref_out / "summary.csv")


# -- backends -------------------------------------------------------------------------------------------
def _subset(rows):
    keys = {t.key for t in SUBSET.trials()}
    return [r for r in rows if r["key"] in keys]


def test_the_local_process_pool_gives_the_same_rows(reference, tmp_path):
    rows = _subset(reference[0])
    pool_rows = run_sweep(SUBSET, tmp_path, backend="local", workers=2, progress=False, report=False)
    assert _rows_without_timing(pool_rows) == _rows_without_timing(rows)


def test_the_ray_backend_gives_the_same_rows(reference, tmp_path):
    ray = pytest.importorskip("ray")
    rows = _subset(reference[0])
    try:
        ray_rows = run_sweep(SUBSET, tmp_path, backend="ray", workers=2, progress=False, report=False,
                             ray_init={"num_cpus": 2, "include_dashboard": False})
    finally:
        if ray.is_initialized():
            ray.shutdown()
    assert _rows_without_timing(ray_rows) == _rows_without_timing(rows)
    assert len((tmp_path / "trials.jsonl").read_text().splitlines()) == len(rows)


# -- command line ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("args, message", [
    (["--methods", "paper,kalman"], "unknown method"),
    (["--scenarios", "no_such_scenario"], ""),
    (["--seeds", "0"], "--seeds"),
    (["--address", "auto"], "--backend ray"),
    (["--truth-engine", "bullet,ode"], "truth engines must be among bullet, mujoco"),
    (["--param-scale", "1,x"], "--param-scale"),
    (["--param-scale", "0"], "parameter scales must be > 0"),
])
def test_cli_rejects_bad_arguments(args, message, tmp_path, capsys):
    assert evaluate_cli.main([*args, "--out", str(tmp_path), "--quiet"]) == 2
    assert message in capsys.readouterr().err


def test_an_estimator_configuration_file_changes_the_particle_methods_only(tmp_path, capsys):
    cfg_file = tmp_path / "noisy.yaml"
    cfg_file.write_text("noise:\n  position_std: 0.03\nreasoner: {d_sim_perc: 0.06}\n")
    out = tmp_path / "out"
    args = ["--scenarios", "cup_falls_behind_box", "--seeds", "1", "--methods", "paper,particles",
            "--particles", str(K), "--duration", "1.0", "--workers", "1", "--quiet", "--out", str(out)]
    assert evaluate_cli.main([*args, "--config", str(cfg_file)]) == 0
    rows = {r["method"]: r for r in read_rows(out / "trials.jsonl")}
    assert "config" not in rows["paper"] and json.loads(rows["particles"]["config"])["noise"]["position_std"] == 0.03
    assert rows["particles"]["key"].split("__")[-1].startswith("cfg") and "cfg" not in rows["paper"]["key"]
    assert "estimator configuration" in (out / "summary.md").read_text()
    # the configuration reaches the estimator: the same trial without the file is another row
    from experiments.evaluation.methods import method_config
    with_file = method_config("particles", K, rows["particles"]["config"])
    assert with_file.noise.position_std == 0.03 and with_file.reasoner.d_sim_perc == 0.06
    assert with_file.noise.motion_noise == method_config("particles", K).noise.motion_noise
    assert evaluate_cli.main(args) == 0  # without the file: the paper's row is reused, particles runs again
    assert sorted(r["method"] for r in read_rows(out / "trials.jsonl")) == ["paper", "particles", "particles"]
    # the sweep sets K and workers; bad fields are located
    (tmp_path / "k.yaml").write_text("noise: {position_std: 0.01}\nparticles: 8\n")
    assert evaluate_cli.main([*args, "--config", str(tmp_path / "k.yaml")]) == 2
    assert "k.yaml:2: particles:" in capsys.readouterr().err
    (tmp_path / "bad.yaml").write_text("noise:\n  position_std: -1\n")
    assert evaluate_cli.main([*args, "--config", str(tmp_path / "bad.yaml")]) == 2
    assert "bad.yaml:2: noise.position_std:" in capsys.readouterr().err


def test_sweep_config_expands_methods_once_per_particle_count():
    cfg = SweepConfig(("cup_falls_behind_box",), (0, 1), ("last-seen", "paper", "particles"), (8, 16))
    keys = [t.key for t in cfg.trials()]
    assert len(keys) == len(set(keys)) == 2 * (1 + 1 + 2)
    assert [t.trace for t in cfg.trials()] == [t.seed == 0 for t in cfg.trials()]
    with pytest.raises(ValueError):
        SweepConfig(("cup_falls_behind_box",), (0,), ("kalman",))


def test_rerun_recording_of_a_trial_does_not_change_its_row(tmp_path):
    pytest.importorskip("experiments.recording")
    spec = TrialSpec("cup_falls_behind_box", 0, "particles", K, 1.0)
    recorded = run_trial(TrialSpec(spec.scenario, spec.seed, spec.method, K, 1.0, rerun_dir=str(tmp_path)))
    assert (tmp_path / f"{spec.key}.rrd").stat().st_size > 0
    assert deterministic_part(recorded["row"]) == deterministic_part(run_trial(spec)["row"])


def test_a_failing_trial_is_reported_and_retried_by_the_next_run(tmp_path, monkeypatch):
    import experiments.evaluation.sweep as ev
    import experiments.evaluation.trials as trials

    cfg = SweepConfig(("cup_falls_behind_box",), (0, 1), ("paper",), (K,), 1.0)
    bad = "cup_falls_behind_box__s1__paper__K1__1s"

    def fine(spec):
        return {"row": {"key": spec.key, "scenario": spec.scenario, "seed": spec.seed, "method": spec.method,
                        "particles": spec.particles}, "trace": None}

    def fake(spec):
        if spec.key == bad:
            raise FloatingPointError("exploded")
        return fine(spec)

    monkeypatch.setattr(trials, "run_trial", fake)
    with pytest.raises(ev.TrialFailures, match="1 of 2"):
        run_sweep(cfg, tmp_path, workers=1, progress=False, report=False)
    assert [r["key"] for r in read_rows(tmp_path / "trials.jsonl")] == ["cup_falls_behind_box__s0__paper__K1__1s"]
    err = json.loads((tmp_path / "errors.jsonl").read_text().splitlines()[0])
    assert err["key"] == bad and "FloatingPointError" in err["error"]
    monkeypatch.setattr(trials, "run_trial", fine)
    ran = []
    run_sweep(cfg, tmp_path, workers=1, progress=False, report=False, on_row=ran.append)
    assert [r["key"] for r in ran] == [bad]


def test_pooled_event_counts_add_up_over_trials():
    def row(method, seed, **counts):
        r = {"method": method, "particles": 4 if method == "particles" else 1, "scenario": "s", "seed": seed}
        for a in ("pick", "place", "release", "push"):
            r.update({f"{a}_true": 0, f"{a}_est": 0, f"{a}_matched": 0})
        r.update(counts)
        return r
    rows = [row("particles", 0, push_true=1, push_est=1, push_matched=1, pick_est=1),
            row("particles", 1, push_true=1, push_est=0, push_matched=0, place_true=2, place_est=2, place_matched=2),
            row("paper", 0, push_true=1, pick_est=1, place_est=1),
            {"method": "paper", "particles": 1, "scenario": "s", "seed": 1}]  # an old row: no counts
    got = {(c["method"], c["action"]): c for c in pooled_event_counts(rows)}
    push = got[("particles", "Push")]
    assert (push["n_true"], push["n_est"], push["n_matched"], push["trials"]) == (2, 1, 1, 2)
    assert push["precision"] == 1.0 and push["recall"] == 0.5 and push["f1"] == pytest.approx(2 / 3)
    assert got[("particles", "Pick")]["precision"] == 0.0 and math.isnan(got[("particles", "Pick")]["recall"])
    assert math.isnan(got[("particles", "Release")]["f1"])
    assert got[("paper", "Push")]["f1"] == 0.0 and got[("paper", "Push")]["trials"] == 1
    md = markdown_event_section(rows)
    assert "| particles (K=4) | Push | 2 | 1 | 1 | 1.00 | 0.50 | 0.67 |" in md
    assert markdown_event_section([]) == ""


def test_truth_conditions_are_trials_of_their_own_reported_side_by_side(tmp_path):
    """--truth-engine bullet,mujoco --param-scale 1,2: each (engine, scale) is a condition whose
    trials are keyed apart (Bullet's at scale 1 keep their keys), summarised and tested on their own,
    and set side by side at the top of summary.md."""
    cfg = SweepConfig(("ball_rolls_behind_box",), (0,), ("paper", "particles"), (K,), 1.5,
                      engines=("bullet", "mujoco"), param_scales=(1.0, 2.0))
    specs = cfg.trials()
    assert len(specs) == 8 and len({s.key for s in specs}) == 8
    plain = [s for s in specs if s.engine == "bullet" and s.param_scale == 1.0]
    assert all("mujoco" not in s.key and "__ps" not in s.key for s in plain)
    rows = run_sweep(cfg, tmp_path, workers=1, progress=False)
    assert {(r["engine"], r["param_scale"]) for r in rows} == {("bullet", 1.0), ("bullet", 2.0), ("mujoco", 1.0),
                                                               ("mujoco", 2.0)}
    for r in rows:
        if r["method"] == "particles":
            assert r["invariant_violations"] == 0  # no particle ever inside the table
    text = (tmp_path / "summary.md").read_text()
    table = text.split("## The truth conditions side by side")[1].split("\n# ")[0]
    for label in ("MuJoCo truth |", "MuJoCo truth, parameters x2 |", "Bullet truth |", "Bullet truth, parameters x2 |"):
        assert label in table
    assert text.index("# MuJoCo truth") < text.index("# Bullet truth")
    summary = list(csv.DictReader(open(tmp_path / "summary.csv")))
    assert {(r["engine"], r["param_scale"]) for r in summary} == {("bullet", "1.0"), ("bullet", "2.0"),
                                                                  ("mujoco", "1.0"), ("mujoco", "2.0")}
