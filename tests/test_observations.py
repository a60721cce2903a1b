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
