import json

import numpy as np
import pytest

from estimator.observations import ObservationReader, parse_frame, read_observations, write_observations
from physics.errors import ObservationError

from helpers import write_jsonl

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

from hypothesis import given, strategies as st  # noqa: E402

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
