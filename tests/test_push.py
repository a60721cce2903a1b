"""actions.push alone, on hand-built arrays: the hold record, lifts, and the events that end episodes."""
import numpy as np
import pytest

from actions.modes import NO_EVENT, PICK, PLACE, PUSH, RELEASE
from actions.push import (
    AIRBORNE,
    HOLD_FIELDS,
    PICK_T,
    REF_Z,
    SMOOTH_Z,
    TOP_Z,
    empty_holds,
    end_codes,
    end_holds,
    late_picks,
    lifted,
    track_holds,
    unrested_picks,
    withdraw_picks,
)


def test_empty_holds_know_nothing():
    h = empty_holds((3, 2))
    assert h.shape == (3, 2, HOLD_FIELDS) and np.all(np.isnan(h))


def test_unrested_picks_are_dropped():
    holds = empty_holds((1, 3))
    holds[0, 0, REF_Z] = 0.7  # rested on the table
    codes = np.array([[PICK, PICK, RELEASE]], dtype=np.int8)
    out = unrested_picks(codes, holds)
    assert out.tolist() == [[PICK, NO_EVENT, RELEASE]] and out.dtype == np.int8
    assert codes.tolist() == [[PICK, PICK, RELEASE]]  # a new array


def test_an_episode_from_rest_smooths_its_height_and_keeps_the_highest():
    h = empty_holds((2,))
    none = np.zeros(2, bool)
    # object 0 rests free at 0.70 m; object 1 never rests
    h = track_holds(h, none, np.array([True, False]), np.ones(2, bool), np.zeros(2), np.array([0.70, 1.0]),
                    none, none, 0.5, 0.5)
    assert h[0, REF_Z] == 0.70 and np.isnan(h[1, REF_Z]) and np.all(np.isnan(h[:, SMOOTH_Z]))
    # both become held at t = 1.0: object 0 by a Pick, now at 0.74; object 1 (no Pick) at 1.0
    held = np.ones(2, bool)
    h = track_holds(h, held, none, np.ones(2, bool), np.array([0.70, 1.0]), np.array([0.74, 1.0]),
                    np.array([True, False]), none, 1.0, 0.5)
    assert h[0, PICK_T] == 1.0 and np.isnan(h[1, PICK_T])
    assert h[0, SMOOTH_Z] == pytest.approx(0.72) and h[0, TOP_Z] == pytest.approx(0.72)
    assert np.isnan(h[1, REF_Z]) and h[1, SMOOTH_Z] == 1.0  # starts where it was, keeps no rest height
    # down again to 0.70, not supported this time: the top stays, airborne is set
    h = track_holds(h, held, none, np.array([False, True]), np.array([0.74, 1.0]), np.array([0.70, 1.0]),
                    none, none, 1.1, 0.5)
    assert h[0, SMOOTH_Z] == pytest.approx(0.71) and h[0, TOP_Z] == pytest.approx(0.72)
    assert h[:, AIRBORNE].tolist() == [1.0, 0.0] and h[0, PICK_T] == 1.0  # the episode goes on
    # a held object's resting flag does not move its rest height
    assert h[0, REF_Z] == 0.70


def test_an_episode_of_an_object_let_go_before_is_silent():
    h = empty_holds((1,))
    h = track_holds(h, np.ones(1, bool), np.zeros(1, bool), np.zeros(1, bool), np.array([0.9]), np.array([0.8]),
                    np.zeros(1, bool), np.ones(1, bool), 2.0, 0.3)
    assert h[0, PICK_T] == -np.inf


def test_lifted_by_height_or_airborne():
    h = empty_holds((4,))
    h[:, REF_Z] = 0.70
    h[:, TOP_Z] = [0.715, 0.725, 0.715, np.nan]
    h[:, AIRBORNE] = [0.0, 0.0, 1.0, np.nan]
    assert lifted(h, 0.02).tolist() == [False, True, True, False]
    assert lifted(h, 0.01).tolist() == [True, True, True, False]


def test_end_codes_push_unlifted_places_and_silence_silent_episodes():
    h = empty_holds((6,))
    h[:, REF_Z] = 0.70
    h[:, SMOOTH_Z] = 0.71
    h[:, TOP_Z] = [0.71, 0.80, 0.71, 0.71, 0.71, 0.71]
    h[:, AIRBORNE] = 0.0
    h[:, PICK_T] = [1.0, 1.0, np.nan, -np.inf, 1.0, -np.inf]
    codes = np.array([PLACE, PLACE, PLACE, PLACE, RELEASE, RELEASE], dtype=np.int8)
    out, push_t = end_codes(codes, h, 0.02)
    # unlifted with a Pick: Push at the Pick's time; lifted: Place; held since first seen: Place;
    # silent: nothing; a Release stays one
    assert out.tolist() == [PUSH, PLACE, PLACE, NO_EVENT, RELEASE, NO_EVENT]
    assert push_t[0] == 1.0 and np.all(np.isnan(push_t[1:]))
    assert codes[0] == PLACE  # a copy


def test_end_holds_keep_only_the_rest_height_of_what_was_let_go():
    h = np.arange(2 * HOLD_FIELDS, dtype=float).reshape(2, HOLD_FIELDS)
    out = end_holds(h, np.array([True, False]))
    assert np.array_equal(out[0], h[0])
    assert out[1, REF_Z] == h[1, REF_Z] and np.all(np.isnan(np.delete(out[1], REF_Z)))


def test_withdraw_picks_only_the_pushed_ones():
    pick = np.array([1.0, 1.0, -np.inf, 2.0])
    out = withdraw_picks(pick, np.array([1.0, np.nan, np.nan, 1.0]))
    assert out.tolist() == [-np.inf, 1.0, -np.inf, 2.0]


def test_late_picks_date_a_silent_episode_when_its_object_is_seen_to_start_moving():
    # three particles hold the object in a silent episode (pick_t NaN or -inf) begun from rest
    holds = empty_holds((4, 1))
    holds[:, 0, REF_Z] = 0.62
    holds[:, 0, SMOOTH_Z] = 0.63
    holds[:3, 0, PICK_T] = [np.nan, -np.inf, np.nan]
    holds[3, 0, PICK_T] = 1.2  # an episode with its Pick already
    held = np.array([[True], [True], [True], [True]])
    codes = np.zeros((4, 1), dtype=np.int8)
    times = np.full((4, 1), np.nan)
    quiet = np.array([[False], [False], [True], [False]])  # the third: carried on a held tray
    c, tm, h = late_picks(codes, times, holds, held, np.array([1.37]), quiet, since=0.5, t=1.5)
    assert c[:, 0].tolist() == [PICK, PICK, NO_EVENT, NO_EVENT]
    assert tm[:2, 0].tolist() == [1.37, 1.37] and np.isnan(tm[2:, 0]).all()
    assert h[:2, 0, PICK_T].tolist() == [1.37, 1.37] and h[3, 0, PICK_T] == 1.2 and np.isnan(h[2, 0, PICK_T])
    assert np.isnan(holds[0, 0, PICK_T])  # inputs untouched
    # still (no onset), an onset out of the window, an object that never rested, not held: none
    for onset, since, ref, hld in ((np.nan, 0.5, 0.62, True), (0.3, 0.5, 0.62, True),
                                   (1.37, 0.5, np.nan, True), (1.37, 0.5, 0.62, False)):
        hh = holds.copy()
        hh[:, 0, REF_Z] = ref
        c, _, _ = late_picks(codes, times, hh, np.full((4, 1), hld), np.array([onset]), quiet, since=since, t=1.5)
        assert (c == NO_EVENT).all()
