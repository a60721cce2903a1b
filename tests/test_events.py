import numpy as np

from actions.events import events_from_switches
from actions.modes import PICK, RELEASE


def test_event_probabilities_are_weights_of_switching_particles():
    codes = np.array([[PICK, 0], [PICK, RELEASE], [0, RELEASE], [0, 0]])
    w = np.array([0.4, 0.3, 0.2, 0.1])
    ev = events_from_switches(codes, 1.5, ["cup", "ball"], w)
    got = {(e.subject, e.action): e.p for e in ev}
    assert got == {("cup", "Pick"): 0.7, ("ball", "Release"): 0.5}
    assert all(e.t == 1.5 for e in ev)
    assert events_from_switches(codes, 1.5, ["cup", "ball"], w, threshold=0.6)[0].action == "Pick"
    single = events_from_switches(np.array([0, PICK]), 2.0, ["cup", "ball"])
    assert single[0].to_json() == {"t": 2.0, "action": "Pick", "subject": "ball", "p": 1.0}
