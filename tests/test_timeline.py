import json

from actions.events import EventRecord
from estimator.timeline import Timeline


def test_facts_open_and_close_with_confidence(tmp_path):
    tl = Timeline(threshold=0.5)
    key = ("isOnTop", "cup", "table")
    tl.observe_facts(0.0, {key: 0.9})
    tl.observe_facts(0.1, {key: 0.7})
    tl.observe_facts(0.2, {key: 0.3})
    tl.observe_facts(0.3, {("isHeld", "cup", None): 1.0})
    doc = tl.to_json()
    assert doc["facts"][0] == {"predicate": "isOnTop", "subject": "cup", "object": "table", "start": 0.0,
                               "end": 0.2, "confidence": 0.8}
    assert doc["facts"][1]["end"] is None and doc["t_end"] == 0.3
    tl.write(str(tmp_path / "t.json"))
    assert json.loads((tmp_path / "t.json").read_text()) == doc


def test_events_enter_once_and_keep_their_highest_probability():
    tl = Timeline(threshold=0.5, merge=0.3)
    assert tl.observe_events(1.0, [EventRecord(1.0, "Release", "cup", 0.3)]) == []
    new = tl.observe_events(1.1, [EventRecord(1.05, "Release", "cup", 0.6)])
    assert len(new) == 1 and new[0].p == 0.6
    assert tl.observe_events(1.2, [EventRecord(1.04, "Release", "cup", 0.9)]) == []
    assert len(tl.events) == 1 and tl.events[0].p == 0.9 and tl.events[0].t == 1.04
    # the same kind of action again, later: a new event
    assert len(tl.observe_events(2.0, [EventRecord(2.0, "Release", "cup", 1.0)])) == 1
    # below threshold: the key closes, and a later crossing is a new event
    tl.observe_events(3.5, [])
    assert len(tl.observe_events(3.6, [EventRecord(2.1, "Release", "cup", 0.7)])) == 1
    assert [e["t"] for e in tl.to_json()["events"]] == [1.04, 2.0, 2.1]
