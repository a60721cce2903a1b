"""``scene-estimator track`` end to end on a short simulated scenario."""
import json

import pytest

from estimator.observations import ObservationReader
from experiments.cli import main
from experiments.simulation.simulator import simulate, write_outputs
from physics.scene import load_scene


@pytest.fixture(scope="module")
def cup_run(tmp_path_factory):
    """cup_falls_behind_box, 1.5 s: the cup is hidden behind the box from the start."""
    out = tmp_path_factory.mktemp("cup")
    paths = write_outputs(simulate("cup_falls_behind_box", seed=0, duration=1.5), out)
    return out, str(paths["scene.yaml"]), str(paths["observations.jsonl"])


def _ids_per_frame(path, ids):
    return [set(f.objects) for f in ObservationReader(path, ids)]


def test_track_stream_is_an_observation_stream(cup_run, capsys):
    out, scene, obs = cup_run
    ids = load_scene(scene).object_ids
    raw = list(ObservationReader(obs, ids))
    plain, fed = str(out / "tracked.jsonl"), str(out / "tracked_fb.jsonl")
    assert main(["track", "--scene", scene, "--observations", obs, "--out", plain, "--quiet"]) == 0
    assert main(["track", "--scene", scene, "--observations", obs, "--out", fed, "--feedback",
                 "--particles", "4", "--workers", "0", "--seed", "1"]) == 0
    assert "pseudo-measurement" in capsys.readouterr().out
    for path in (plain, fed):
        frames = list(ObservationReader(path, ids))  # parses with the project's reader
        assert [f.t for f in frames] == [f.t for f in raw]  # one line per input frame
        assert all(d.position_std is not None and d.position_std > 0 for f in frames for d in f.objects.values())
    # the cup is never detected: the tracker alone never has it, with feedback it is in every frame
    assert not any("cup" in f.objects for f in raw)
    assert not any("cup" in ids_ for ids_ in _ids_per_frame(plain, ids))
    fed_frames = list(ObservationReader(fed, ids))
    assert all("cup" in f.objects for f in fed_frames)
    cup = [f.objects["cup"] for f in fed_frames]
    assert all(0.0 < c.position_std < 0.2 and c.orientation is not None for c in cup)
    # the detected box follows its detections within a few of its standard deviations
    for f, r in zip(fed_frames, raw):
        if "box" in r.objects:
            d = f.objects["box"]
            assert abs(d.position - r.objects["box"].position).max() < 0.05
    # restarting hidden tracks at the belief instead of fusing it gives the same objects
    replaced = str(out / "tracked_replace.jsonl")
    assert main(["track", "--scene", scene, "--observations", obs, "--out", replaced, "--feedback", "--quiet",
                 "--fusion", "replace", "--particles", "4", "--workers", "0", "--seed", "1"]) == 0
    assert _ids_per_frame(replaced, ids) == _ids_per_frame(fed, ids)
    # `run` accepts the tracked stream
    assert main(["run", "--scene", scene, "--observations", fed, "--quiet", "--paper", "--out", str(out / "e.jsonl")]) == 0
    assert len((out / "e.jsonl").read_text().splitlines()) >= 10


def test_track_reports_bad_input_like_run(cup_run, capsys):
    out, scene, obs = cup_run
    bad = out / "bad.jsonl"
    lines = open(obs).read().splitlines()
    lines[2] = '{"t": 0.1, "objects": {"box": {"position": [0, NaN, 1]}}}'
    bad.write_text("\n".join(lines) + "\n")
    assert main(["track", "--scene", scene, "--observations", str(bad), "--out", str(out / "x.jsonl")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3: objects.box.position[1]: non-finite" in err and "Traceback" not in err
    assert main(["track", "--scene", scene, "--observations", str(out / "nope.jsonl"),
                 "--out", str(out / "x.jsonl")]) == 2
    assert "observation file not found" in capsys.readouterr().err
    assert main(["track", "--scene", scene, "--observations", obs, "--out", str(out / "x.jsonl"),
                 "--skip-bad-frames", "--quiet", "--measurement-std", "0"]) == 2
    assert "measurement_std" in capsys.readouterr().err
