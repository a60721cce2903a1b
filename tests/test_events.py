import numpy as np

from actions.events import N_ACTIONS, recent_events, record_event_times
from actions.modes import PICK, PLACE, PUSH, RELEASE


def test_recent_events_are_weighted_and_carried_by_particles():
    event_t = np.full((4, 2, N_ACTIONS), -np.inf)
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
    single = recent_events(np.where(np.arange(N_ACTIONS) == PLACE - 1, 2.0, -np.inf)[None, None, :], np.ones(1), 2.0,
                           1.0, ["cup"])
    assert single[0].to_json() == {"t": 2.0, "action": "Place", "subject": "cup", "p": 1.0}


def test_a_push_takes_its_picks_time_and_withdraws_that_pick():
    event_t = np.full((3, 2, N_ACTIONS), -np.inf)
    decided = np.full((3, 2), -np.inf)
    record_event_times(event_t, np.array([[PICK, PICK], [PICK, 0], [PICK, 0]]), 1.0)
    record_event_times(event_t, np.array([[0, 0], [0, 0], [PICK, 0]]), 1.4)  # particle 2 picked again later
    # at 3.0: particles 0 and 2 let the cup go unlifted (a Push since their Pick at 1.0 resp. 1.4),
    # particle 1 puts it down lifted (a Place); the ball's Push in particle 0 started at 1.0 too
    codes = np.array([[PUSH, PUSH], [PLACE, 0], [PUSH, 0]])
    push_t = np.array([[1.0, 1.0], [np.nan, np.nan], [1.4, np.nan]])
    record_event_times(event_t, codes, 3.0, push_t, decided)
    assert event_t[:, 0, PICK - 1].tolist() == [-np.inf, 1.0, -np.inf]  # withdrawn where pushed
    assert event_t[:, 0, PUSH - 1].tolist() == [1.0, -np.inf, 1.4]
    assert event_t[:, 0, PLACE - 1].tolist() == [-np.inf, 3.0, -np.inf]
    assert decided[:, 0].tolist() == [3.0, -np.inf, 3.0] and decided[0, 1] == 3.0 and decided[1, 1] == -np.inf
    # without push times a Push is recorded when decided, and the Pick at another time stays
    e2 = np.full((1, 1, N_ACTIONS), -np.inf)
    record_event_times(e2, np.array([[PICK]]), 0.5)
    record_event_times(e2, np.array([[PUSH]]), 2.0)
    assert e2[0, 0, PUSH - 1] == 2.0 and e2[0, 0, PICK - 1] == 0.5


def test_a_push_is_recent_from_its_decision_not_from_its_start():
    event_t = np.full((4, 1, N_ACTIONS), -np.inf)
    decided = np.full((4, 1), -np.inf)
    event_t[:2, 0, PUSH - 1] = [1.0, 1.2]  # pushes that began 2 s before they were decided
    decided[:2, 0] = 3.0
    event_t[2, 0, PICK - 1] = 1.1
    w = np.array([0.25, 0.25, 0.4, 0.1])
    ev = recent_events(event_t, w, 3.1, 1.0, ["box"], push_decided=decided)
    assert [(e.action, round(e.p, 12), round(e.t, 12)) for e in ev] == [("Push", 0.5, 1.1)]
    assert recent_events(event_t, w, 3.1, 1.0, ["box"]) == []  # by their start, they are old
    assert recent_events(event_t, w, 4.1, 1.0, ["box"], push_decided=decided) == []  # and later forgotten
