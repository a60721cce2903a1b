import json

import numpy as np
import pytest

from estimator.observations import ObservationReader, parse_frame, read_observations, write_observations
from helpers import write_jsonl
from physics.errors import ObservationError

IDS = ["cup", "box"]
GOOD = {"t": 0.0, "objects": {"cup": {"position": [0.1, 0.2, 0.7], "orientation": [0, 0, 0, 2]}},
        "hands": {"human/right": [0.3, -0.1, 0.9]}}


def test_reads_and_normalises(tmp_path):
    p = tmp_path / "o.jsonl"
    write_jsonl(p, [GOOD, "", {"t": 0.1, "objects": {"box": {"position": [0, 0, 1], "position_std": 0.02}}}])
    frames = read_observations(str(p), IDS)
    assert [f.t for f in frames] == [0.0, 0.1]
    assert np.allclose(frames[0].objects["cup"].orientation, [0, 0, 0, 1])
    assert frames[0].hands["human/right"].tolist() == [0.3, -0.1, 0.9]
    assert frames[1].objects["box"].orientation is None and frames[1].objects["box"].position_std == 0.02
    assert frames[1].line == 3
    out = tmp_path / "again.jsonl"
    write_observations(str(out), frames)
    assert [f.t for f in read_observations(str(out), IDS)] == [0.0, 0.1]


BAD_LINES = [
    ('{"t": 0.1, "objects": {', "invalid JSON", None),
    ('{"t": 0.1, "objects": {"cup": {"position": [0, NaN, 1]}}}', "non-finite", "objects.cup.position[1]"),
    ('{"t": 0.1, "objects": {"cup": {"position": [0, Infinity, 1]}}}', "non-finite", "objects.cup.position[1]"),
    ('{"t": 0.1, "objects": {"cup": {"position": [0, 0, 1], "orientation": [0, 0, 0, 0]}}}',
     "zero-length quaternion", "objects.cup.orientation"),
    ('{"t": 0.1, "objects": {"mug": {"position": [0, 0, 1]}}}', "unknown object id", "objects.mug"),
    ('{"t": -1.0, "objects": {}}', "strictly increasing", "t"),
    ('{"t": 0.0, "objects": {}}', "strictly increasing", "t"),
    ('{"objects": {}}', "missing", "t"),
    ('{"t": 0.1, "objects": {"cup": {"position": [0, 0]}}}', "list of 3", "objects.cup.position"),
    ('{"t": 0.1, "objects": {"cup": {"position": [0, 0, "a"]}}}', "must be a number", "objects.cup.position[2]"),
]


@pytest.mark.parametrize("line, words, field", BAD_LINES)
def test_each_bad_frame_names_file_line_and_field(tmp_path, line, words, field):
    p = tmp_path / "o.jsonl"
    write_jsonl(p, [GOOD, line, {"t": 0.2, "objects": {}}])
    with pytest.raises(ObservationError) as e:
        list(ObservationReader(str(p), IDS))
    assert words in str(e.value)
    assert e.value.path == str(p) and e.value.line == 2 and e.value.field == field
    # --skip-bad-frames: counted, reported, and the rest is read
    warnings = []
    reader = ObservationReader(str(p), IDS, skip_bad_frames=True, warn=warnings.append)
    frames = list(reader)
    assert [f.t for f in frames] == [0.0, 0.2]
    assert reader.skipped == 1 and len(warnings) == 1 and words in warnings[0]


def test_missing_file_and_non_object():
    with pytest.raises(ObservationError, match="not found"):
        list(ObservationReader("/nonexistent/o.jsonl", IDS))
    with pytest.raises(ObservationError, match="JSON object"):
        parse_frame([1, 2], known_ids=IDS)
    f = parse_frame(json.loads('{"t": 1, "objects": {"cup": {"position": [1, 2, 3]}}}'))
    assert f.objects["cup"].position.tolist() == [1, 2, 3]


# -- property-based: any content gives frames of finite numbers or an ObservationError with its line ------

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st

from helpers import fuzz_settings, json_values  # noqa: E402

_IDS = ["cup", "box"]
_DETECTION = st.fixed_dictionaries(
    {"position": st.one_of(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2, max_size=4),
                           json_values())},
    optional={"orientation": st.one_of(st.lists(st.floats(-2, 2), min_size=3, max_size=5), json_values()),
              "position_std": json_values()})
_FRAME = st.fixed_dictionaries(
    {"t": st.one_of(st.floats(allow_nan=True, allow_infinity=True), json_values())},
    optional={"objects": st.one_of(st.dictionaries(st.sampled_from(_IDS + ["unknown"]), _DETECTION, max_size=3),
                                   json_values()),
              "hands": st.one_of(st.dictionaries(st.text(max_size=4), st.lists(st.floats(), min_size=3, max_size=3),
                                                 max_size=2), json_values())})
_LINE = st.one_of(_FRAME.map(json.dumps), st.text(max_size=30), json_values().map(json.dumps))


@fuzz_settings(300)
@given(st.lists(_LINE, min_size=1, max_size=6), st.booleans())
def test_any_stream_gives_finite_frames_or_a_located_error(tmp_path_factory, lines, skip):
    path = tmp_path_factory.mktemp("fuzz") / "o.jsonl"
    path.write_text("\n".join(lines) + "\n")
    reader = ObservationReader(str(path), _IDS, skip_bad_frames=skip)
    try:
        frames = list(reader)
    except ObservationError as exc:
        assert not skip and str(path) in str(exc) and ":" in str(exc)
        return
    assert len(frames) + reader.skipped <= len(path.read_text().splitlines())
    assert all(b.t > a.t for a, b in zip(frames, frames[1:]))
    for f in frames:
        assert np.isfinite(f.t) and set(f.objects) <= set(_IDS)
        for d in f.objects.values():
            assert np.isfinite(d.position).all()
            assert d.orientation is None or np.isclose(np.linalg.norm(d.orientation), 1.0)


def test_a_recording_replayed_twice_is_an_error_or_its_replay_is_skipped(tmp_path):
    rows = [{"t": round(0.1 * i, 3), "objects": {"cup": {"position": [0, 0, 0.7]}}} for i in range(5)]
    path = tmp_path / "twice.jsonl"
    write_jsonl(path, rows + rows)  # the clock jumps back to 0 at line 6
    with pytest.raises(ObservationError, match=r"twice.jsonl:6: t"):
        list(ObservationReader(str(path), ["cup"]))
    reader = ObservationReader(str(path), ["cup"], skip_bad_frames=True)
    frames = list(reader)
    assert [f.t for f in frames] == [0.0, 0.1, 0.2, 0.3, 0.4] and reader.skipped == 5


# -- per-frame cameras -----------------------------------------------------------------------------------

HEAD = {"id": "head", "position": [0.3, 0.2, 1.5], "target": [0.3, 0.2, 0.6], "up": [1, 0, 0], "fov_deg": 20}


def test_frame_cameras_are_read_written_back_and_may_be_given_by_orientation(tmp_path):
    s = 0.5 ** 0.5
    down = {"id": "wrist", "position": [0.0, 0.0, 1.0], "orientation": [1.0, 0.0, 0.0, 0.0]}  # z forward -> -z
    side = {"position": [1.0, 0.0, 1.0], "orientation": [0.0, s, 0.0, s]}  # z forward -> +x... turned
    frame = parse_frame({"t": 0.0, "objects": {}, "cameras": [HEAD, down, side]}, known_ids=IDS)
    assert list(frame.cameras) == ["head", "wrist", "2"]
    assert np.allclose(frame.cameras["wrist"].target, [0.0, 0.0, 0.0])  # one metre along -z
    assert np.allclose(frame.cameras["2"].target, [2.0, 0.0, 1.0])  # rotated +90 deg about y: z -> +x
    assert frame.cameras["head"].fov_deg == 20 and frame.cameras["head"].far == 4.0
    p = tmp_path / "o.jsonl"
    write_observations(str(p), [frame, parse_frame({"t": 0.1, "objects": {}})])
    again = read_observations(str(p), IDS)
    assert again[0].cameras == frame.cameras and again[1].cameras is None
    assert "cameras" not in json.loads(p.read_text().splitlines()[1])  # old frames stay as they were


@pytest.mark.parametrize("cameras, field, message", [
    ({"id": "head"}, "cameras", "must be a list"),
    ([{"id": "head", "target": [0, 0, 0]}], r"cameras\[0\]", "missing field 'position'"),
    ([{"id": "head", "position": [0, 0, 1]}], r"cameras\[0\]", "missing field 'target'"),
    ([dict(HEAD, fov_deg=-3)], r"cameras\[0\].fov_deg", "must be > 0"),
    ([dict(HEAD, far=0.05)], r"cameras\[0\].far", "greater than"),
    ([dict(HEAD, lens="wide")], r"cameras\[0\].lens", "unknown field"),
    ([dict(HEAD, orientation=[0, 0, 0, 1])], r"cameras\[0\].orientation", "either target or orientation"),
    ([HEAD, HEAD], r"cameras\[1\].id", "duplicate camera id"),
    ([dict(HEAD, id=3)], r"cameras\[0\].id", "non-empty string"),
])
def test_bad_frame_cameras_are_located_errors(tmp_path, cameras, field, message):
    p = tmp_path / "o.jsonl"
    write_jsonl(p, [{"t": 0.0, "objects": {}}, {"t": 0.1, "objects": {}, "cameras": cameras}])
    with pytest.raises(ObservationError, match=rf"o.jsonl:2: {field}: .*{message}"):
        read_observations(str(p), IDS)


def test_a_frame_camera_gives_negative_evidence_where_it_looks_and_the_scene_camera_no_longer_does():
    from estimator.config import EstimatorConfig, NoiseConfig
    from estimator.filter import SceneEstimator
    from estimator.observations import Frame
    from helpers import TABLE_TOP, table_scene
    from physics.scene import CameraSpec

    spot_a, spot_b = [0.3, 0.2, TABLE_TOP + 0.05], [-0.3, -0.2, TABLE_TOP + 0.05]
    scene_cam = {"position": [-0.3, -0.2, 1.5], "target": [-0.3, -0.2, 0.6], "up": [1, 0, 0], "fov_deg": 20}
    scene = table_scene({"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "pose": {"position": spot_a}},
                        camera=scene_cam)
    head = CameraSpec(position=(0.3, 0.2, 1.5), target=(0.3, 0.2, 0.6), up=(1.0, 0.0, 0.0), fov_deg=20.0)

    def weights(frame_cameras):
        cfg = EstimatorConfig(particles=2, noise=NoiseConfig.off(), resample_threshold=0.0)
        with SceneEstimator(scene, cfg, np.random.default_rng(0)) as est:
            est.update(Frame(0.0, {}))
            cup = est.object_ids.index("cup")
            est.state.poses[0, cup, :3], est.state.poses[1, cup, :3] = spot_a, spot_b
            belief = est.update(Frame(0.08, {}, cameras=frame_cameras))
            return belief.weights

    miss = NoiseConfig.off().miss_prob
    # the scene's camera (no cameras in the frame) sees spot B: particle 1 pays the miss probability
    assert np.allclose(weights(None), [1 / (1 + miss), miss / (1 + miss)])
    # the head camera took this frame: it sees spot A, and the scene camera no longer counts
    assert np.allclose(weights({"head": head}), [miss / (1 + miss), 1 / (1 + miss)])
    # no camera took it: no negative evidence at all
    assert np.allclose(weights({}), [0.5, 0.5])


def test_an_open_stream_is_read_as_it_comes_and_named_in_errors():
    import io
    lines = [json.dumps(dict(GOOD, t=k / 10)) for k in range(3)] + ['{"t": 0.3, "objects": {"mug": {}}}']
    fh = io.StringIO("\n".join(lines) + "\n")
    reader = ObservationReader("<stdin>", IDS, stream=fh)
    it = iter(reader)
    assert [next(it).t for _ in range(3)] == [0.0, 0.1, 0.2]
    assert fh.tell() < len(fh.getvalue())  # the bad line is not read before it is asked for
    with pytest.raises(ObservationError, match=r"^<stdin>:4: objects\.mug: unknown object id"):
        next(it)
    assert fh.closed
