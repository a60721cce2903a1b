import numpy as np

from actions.events import recent_events, record_event_times
from actions.modes import PICK, PLACE, RELEASE


def test_recent_events_are_weighted_and_carried_by_particles():
    event_t = np.full((4, 2, 3), -np.inf)
    record_event_times(event_t, np.array([[PICK, 0], [PICK, RELEASE], [0, RELEASE], [0, 0]]), 1.0)
    record_event_times(event_t, np.array([[0, 0], [0, 0], [0, 0], [PICK, 0]]), 1.5)
    w = np.array([0.4, 0.3, 0.2, 0.1])
    ev = recent_events(event_t, w, 1.5, 1.0, ["cup", "ball"])
    got = {(e.subject, e.action): (round(e.p, 12), round(e.t, 12)) for e in ev}
    assert got == {("cup", "Pick"): (0.8, round((0.4 + 0.3 + 0.1 * 1.5) / 0.8, 12)),
                   ("ball", "Release"): (0.5, 1.0)}
    # outside the window the events are forgotten; a threshold filters small probabilities
    late = recent_events(event_t, w, 2.2, 1.0, ["cup", "ball"])
    assert [(e.subject, e.action) for e in late] == [("cup", "Pick")]
    assert abs(late[0].t - 1.5) < 1e-12 and abs(late[0].p - 0.1) < 1e-12
    assert [e.action for e in recent_events(event_t, w, 1.5, 1.0, ["cup", "ball"], threshold=0.6)] == ["Pick"]
    # resampling carries the event memory: after copying particle 3 everywhere, Pick is certain
    ev = recent_events(event_t[[3, 3, 3, 3]], np.full(4, 0.25), 1.5, 1.0, ["cup", "ball"])
    assert [e.action for e in ev] == ["Pick"] and abs(ev[0].p - 1) < 1e-12 and abs(ev[0].t - 1.5) < 1e-12
    single = recent_events(np.where(np.arange(3) == PLACE - 1, 2.0, -np.inf)[None, None, :], np.ones(1), 2.0, 1.0, ["cup"])
    assert single[0].to_json() == {"t": 2.0, "action": "Place", "subject": "cup", "p": 1.0}
