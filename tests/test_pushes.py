"""experiments.simulation.pushes alone: push episodes from hand-built contacts and positions."""
import numpy as np

from experiments.simulation.pushes import PUSH_DISTANCE, PUSH_LIFT, PUSH_START, PushEpisode, PushTracker


def _feed(tracker, path, touching_until, start=1):
    """Feed object 0 along ``path`` ((n, 3) positions, one per step from ``start``), touched while the
    step is <= ``touching_until``; returns the pushes reported and the step after the last."""
    out = []
    for j, p in enumerate(path):
        step = start + j
        out += tracker.step(step, {0} if step <= touching_until else set(), {0: p})
    return out, start + len(path)


def test_a_slide_is_a_push_from_when_it_started_moving():
    tr = PushTracker(gap_steps=10)
    path = np.zeros((60, 3))
    path[:, 2] = 0.7
    path[5:45, 0] = -np.linspace(0.0, 0.1, 40)  # still for 5 steps, then 10 cm in 40 steps
    path[45:, 0] = -0.1
    pushes, _ = _feed(tr, path, touching_until=45)
    first_moved = 1 + next(j for j in range(60) if abs(path[j, 0]) > PUSH_START)
    assert pushes == [(0, first_moved)] and tr.active == {}  # closed 10 steps after the last touch


def test_no_push_when_barely_moved_lifted_or_dropped_or_grasped():
    base = np.zeros((40, 3))
    base[:, 2] = 0.7
    small = base.copy()
    small[:, 0] = np.linspace(0, PUSH_DISTANCE * 0.9, 40)
    lifted = base.copy()
    lifted[:, 0] = np.linspace(0, 0.1, 40)
    lifted[20:, 2] += PUSH_LIFT * 1.5
    dropped = lifted.copy()
    dropped[20:, 2] = 0.05  # off the table
    for path in (small, lifted, dropped):
        tr = PushTracker(gap_steps=5)
        pushes, _ = _feed(tr, path, touching_until=30)
        assert pushes == [] and tr.active == {}
    # grasped in the middle of a push: the episode is forgotten (a Pick, not a push)
    tr = PushTracker(gap_steps=5)
    _feed(tr, lifted[:10], touching_until=10)
    tr.cancel(0)
    assert tr.active == {} and tr.finish() == []


def test_open_episodes_end_with_the_run_and_a_new_touch_starts_a_new_one():
    tr = PushTracker(gap_steps=5)
    path = np.zeros((30, 3))
    path[:, 0] = np.linspace(0, 0.05, 30)
    pushes, nxt = _feed(tr, path, touching_until=100)
    assert pushes == [] and 0 in tr.active  # still touched: still open
    start = 1 + int(np.argmax(np.abs(path[:, 0]) > PUSH_START))
    assert start > 1 and tr.finish() == [(0, start)]
    # a second touch much later is another episode, with its own start
    pushes, nxt = _feed(tr, np.tile([0.05, 0, 0], (10, 1)), touching_until=0, start=nxt)  # untouched: nothing
    assert tr.active == {}
    path2 = np.tile([0.05, 0.0, 0.0], (30, 1))
    path2[10:, 1] = np.linspace(0, 0.04, 20)
    pushes, _ = _feed(tr, path2, touching_until=nxt + 25, start=nxt)
    assert tr.finish() == [(0, nxt + 10 + int(np.argmax(path2[10:, 1] > PUSH_START)))]


def test_episode_update_measures_from_the_first_touch():
    ep = PushEpisode(first_step=3, last_contact=3, ref=np.array([0.0, 0.0, 0.7]))
    ep.update(4, np.array([0.003, 0.0, 0.7]), touching=True)
    assert ep.start_step is None and ep.last_contact == 4
    ep.update(5, np.array([0.03, 0.0, 0.71]), touching=False)
    assert ep.start_step == 5 and ep.last_contact == 4
    assert np.isclose(ep.moved, 0.03) and np.isclose(ep.rise, 0.01) and ep.drop == 0.0 and ep.is_push()
