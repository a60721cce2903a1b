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


def test_events_accumulate_over_the_window():
    tl = Timeline(threshold=0.5, event_window=1.0)
    assert tl.observe_events(1.0, [EventRecord(1.0, "Release", "cup", 0.3)]) == []
    new = tl.observe_events(1.2, [EventRecord(1.2, "Release", "cup", 0.3)])
    assert len(new) == 1 and abs(new[0].p - 0.6) < 1e-12 and abs(new[0].t - 1.1) < 1e-12
    # mass older than the window is forgotten
    assert tl.observe_events(3.0, [EventRecord(3.0, "Pick", "cup", 0.3)]) == []
    assert tl.observe_events(4.5, [EventRecord(4.5, "Pick", "cup", 0.3)]) == []
    # certain events are all kept, even close together
    assert len(tl.observe_events(5.0, [EventRecord(5.0, "Pick", "box", 1.0)])) == 1
    assert len(tl.observe_events(5.1, [EventRecord(5.1, "Pick", "box", 1.0)])) == 1
