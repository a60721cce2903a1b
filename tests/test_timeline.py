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
    # below threshold: the key closes; a later crossing at a time within merge of the recorded
    # Release is that Release, one beyond merge a new event
    tl.observe_events(3.5, [])
    assert tl.observe_events(3.6, [EventRecord(2.1, "Release", "cup", 0.7)]) == []
    tl.observe_events(3.7, [])
    assert len(tl.observe_events(3.8, [EventRecord(2.5, "Release", "cup", 0.7)])) == 1
    assert [e["t"] for e in tl.to_json()["events"]] == [1.04, 2.0, 2.5]


def test_a_push_revises_the_pick_entered_while_the_object_moved():
    tl = Timeline(threshold=0.5, merge=0.3)
    tl.observe_events(0.5, [EventRecord(0.45, "Pick", "cup", 1.0)])  # an earlier, unrelated pick
    tl.observe_events(0.6, [])
    tl.observe_events(1.7, [EventRecord(1.63, "Pick", "box", 0.9)])
    tl.observe_events(1.8, [EventRecord(1.64, "Pick", "box", 1.0)])
    assert [(e.action, e.subject) for e in tl.events] == [("Pick", "cup"), ("Pick", "box")]
    # put down unlifted: the particles withdraw the Pick and report a Push at its time
    new = tl.observe_events(2.9, [EventRecord(1.62, "Pick", "box", 0.5), EventRecord(1.66, "Push", "box", 0.8)])
    assert [(e.action, e.t) for e in new] == [("Push", 1.66)]
    assert [(e.action, e.subject, e.t) for e in tl.events] == [("Pick", "cup", 0.45), ("Push", "box", 1.66)]
    # the Push gains probability; the revised Pick does not come back, though still reported
    tl.observe_events(3.0, [EventRecord(1.62, "Pick", "box", 0.6), EventRecord(1.65, "Push", "box", 0.95)])
    tl.observe_events(3.1, [])
    tl.observe_events(3.2, [EventRecord(1.62, "Pick", "box", 0.6)])
    doc = tl.to_json()["events"]
    assert [(e["action"], e["subject"], e["t"], e["p"]) for e in doc] == [("Pick", "cup", 0.45, 1.0),
                                                                          ("Push", "box", 1.65, 0.95)]
    # a Pick later than the merge window is a new action; a Push far from any Pick revises none
    tl.observe_events(5.0, [EventRecord(4.9, "Pick", "box", 1.0), EventRecord(3.5, "Push", "cup", 1.0)])
    assert [(e.action, e.subject) for e in tl.events] == [("Pick", "cup"), ("Push", "box"), ("Pick", "box"),
                                                         ("Push", "cup")]


def test_an_event_that_leaves_the_window_and_comes_back_is_recorded_once():
    """A Push of a flicked ball enters, drops out of the windowed events, and comes back at the same
    time (some particles decide their let-go later): one Push, with the higher probability; one back
    at a time beyond ``merge`` is a second Push."""
    tl = Timeline(threshold=0.5, merge=0.3)
    tl.observe_events(1.0, [EventRecord(0.53, "Push", "ball", 0.8)])
    tl.observe_events(2.0, [])
    assert tl.observe_events(2.4, [EventRecord(0.55, "Push", "ball", 0.9)]) == []
    assert [(e.action, e.t, e.p) for e in tl.events] == [("Push", 0.53, 0.9)]
    tl.observe_events(2.5, [EventRecord(0.54, "Push", "ball", 0.7)])  # open again: no change
    tl.observe_events(2.6, [])
    tl.observe_events(3.0, [EventRecord(2.9, "Push", "ball", 1.0)])
    assert [(e.action, e.t) for e in tl.events] == [("Push", 0.53), ("Push", 2.9)]


def test_forget_before_keeps_a_bounded_window_and_what_is_still_refined():
    tl = Timeline(threshold=0.5, merge=0.3)
    key = ("isPerceived", "ball", None)
    for k in range(100):  # a fact that opens and closes every second, a Pick every 2 s
        t = float(k)
        tl.observe_facts(t, {key: 1.0} if k % 2 == 0 else {})
        tl.observe_events(t, [EventRecord(t, "Pick", "cup", 0.9)] if k % 2 == 0 else [])
    tl.observe_events(99.5, [EventRecord(99.4, "Release", "cup", 0.8)])  # open: still refined
    before = tl.to_json()
    tl.forget_before(90.0)
    doc = tl.to_json()
    assert doc["kept_since"] == 90.0 and "kept_since" not in before
    assert [f for f in before["facts"] if f["end"] is None or f["end"] >= 90.0] == doc["facts"]
    assert [e for e in before["events"] if e["t"] >= 90.0] == doc["events"]
    assert len(doc["events"]) == 6 and len(doc["facts"]) == 5
    # the open Release is refined in place after the forgetting, not entered twice
    assert tl.observe_events(99.6, [EventRecord(99.45, "Release", "cup", 0.95)]) == []
    assert [(e["action"], e["p"]) for e in tl.to_json()["events"]][-1] == ("Release", 0.95)
    # nothing older to forget: the document does not change
    tl.forget_before(10.0)
    assert tl.to_json()["kept_since"] == 90.0
