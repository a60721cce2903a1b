"""actions.episodes alone, on hand-built arrays: Picks, Places that wait for physics, Pushes."""
import numpy as np
import pytest

from actions.episodes import EpisodeRule, Switches, carried, update_events
from actions.modes import FREE, HELD, NO_EVENT, PICK, PLACE, PUSH, RELEASE
from actions.push import LET_GO_T, PICK_T, REF_Z, empty_holds

F, H = int(FREE), int(HELD)
RULE = EpisodeRule(lift=0.02, smoothing=1.0, wait=0.5)


def step(holds, before, physics, after, t, z, seen_z=None, resting=None, supported=None, acted=None,
         release=None, pick_t=None, carried=None, rolled_off=None):
    """One update of M objects (lists), everything else defaulted: at rest on a support where free."""
    m = len(before)
    arr = lambda v, d: np.asarray(v if v is not None else d)  # noqa: E731
    return update_events(holds, arr(acted, [False] * m), arr(carried, [False] * m), Switches(
        np.array(before, np.int8), np.array(physics, np.int8), np.array(after, np.int8),
        arr(release, [0] * m).astype(np.int8), arr(supported, [True] * m), arr(resting, [a == F for a in after]),
        np.array(z, float), np.array(z, float), arr(seen_z, [np.nan] * m).astype(float),
        arr(pick_t, [t] * m).astype(float), rolled_off=None if rolled_off is None else np.asarray(rolled_off, bool)),
        t, RULE)


def test_a_put_down_waits_for_physics_and_a_drag_is_a_push():
    h = empty_holds((2,))
    h = step(h, [F, F], [F, F], [F, F], 0.1, [0.70, 0.70]).holds  # both rest on the table
    ev = step(h, [F, F], [H, H], [H, H], 1.0, [0.70, 0.70], pick_t=[0.8, 0.8])  # picked: began moving at 0.8
    assert ev.codes.tolist() == [PICK, PICK] and ev.times.tolist() == [0.8, 0.8]
    ev = step(ev.holds, [H, H], [H, H], [H, H], 1.5, [0.90, 0.71])  # object 0 lifted 20 cm, 1 dragged
    # let go on a support at 2.0: nothing yet, the Place waits for physics
    ev = step(ev.holds, [H, H], [H, H], [F, F], 2.0, [0.70, 0.71], resting=[False, False])
    assert ev.codes.tolist() == [NO_EVENT, NO_EVENT] and ev.holds[:, LET_GO_T].tolist() == [2.0, 2.0]
    assert ev.modes.tolist() == [F, F]
    # at rest where let go (the perception within 2 cm): confirmed, at the let-go time
    ev = step(ev.holds, [F, F], [F, F], [F, F], 2.1, [0.70, 0.70], seen_z=[0.71, 0.715])
    assert ev.codes.tolist() == [PLACE, PUSH]
    assert ev.times.tolist() == [2.0, 0.8]  # the Push began when its Pick did
    assert np.all(np.isnan(ev.holds[:, LET_GO_T])) and np.all(np.isnan(ev.holds[:, PICK_T]))
    assert ev.holds[:, REF_Z].tolist() == [0.70, 0.70]  # the old rest height, until it rests anew
    assert step(ev.holds, [F, F], [F, F], [F, F], 2.2, [0.65, 0.70]).holds[0, REF_Z] == 0.65


def _held_and_let_go():
    h = empty_holds((1,))
    h = step(h, [F], [F], [F], 0.1, [0.70]).holds
    h = step(h, [F], [H], [H], 1.0, [0.70]).holds
    h = step(h, [H], [H], [H], 1.5, [0.74]).holds  # held 4 cm up
    return step(h, [H], [H], [F], 2.0, [0.74], resting=[False]).holds


def test_a_place_followed_by_holding_again_was_none_and_the_episode_goes_on():
    ev = step(_held_and_let_go(), [F], [H], [H], 2.1, [0.73])  # diverged: the hand still has it
    assert ev.codes.tolist() == [NO_EVENT] and ev.modes.tolist() == [H]
    assert ev.holds[0, PICK_T] == 1.0 and np.isnan(ev.holds[0, LET_GO_T])  # same episode, same Pick
    ev = step(ev.holds, [H], [H], [F], 3.0, [0.70], resting=[False])
    ev = step(ev.holds, [F], [F], [F], 3.1, [0.70], seen_z=[0.71])
    assert ev.codes.tolist() == [PLACE] and ev.times.tolist() == [3.0]


def test_an_object_that_falls_when_let_go_had_not_been_put_down():
    ev = step(_held_and_let_go(), [F], [F], [F], 2.1, [0.70], seen_z=[0.75])  # rests 5 cm below what is seen
    assert ev.codes.tolist() == [NO_EVENT] and ev.modes.tolist() == [H]
    assert ev.holds[0, PICK_T] == 1.0 and np.isnan(ev.holds[0, LET_GO_T])


def test_a_place_is_confirmed_after_the_wait_and_unseen_objects_are_not_held_again():
    h = _held_and_let_go()
    ev = step(h, [F], [F], [F], 2.3, [0.72], resting=[False])  # still moving: wait
    assert ev.codes.tolist() == [NO_EVENT] and ev.holds[0, LET_GO_T] == 2.0
    ev = step(ev.holds, [F], [F], [F], 2.5, [0.71], resting=[False])
    assert ev.codes.tolist() == [PLACE] and ev.times.tolist() == [2.0]
    ev = step(h, [F], [F], [F], 2.1, [0.73])  # rested where let go, not perceived: a Place
    assert ev.codes.tolist() == [PLACE] and ev.modes.tolist() == [F]


def test_an_unseen_object_resting_far_below_where_it_was_held_was_dropped():
    # held 4 cm up, let go on a support, then not seen, at rest 14 cm lower (into a box): not held
    # again (nothing shows it up there), and not a Place: a Release at the let-go time
    ev = step(_held_and_let_go(), [F], [F], [F], 2.1, [0.60])
    assert ev.codes.tolist() == [RELEASE] and ev.modes.tolist() == [F] and ev.times.tolist() == [2.0]
    # seen at rest where it lies, the episode's record is not asked: a Place (a drop in view is a
    # Release by the falling-detection rule before it comes to this); seen up there, it was held
    # above its support (the test above)
    ev = step(_held_and_let_go(), [F], [F], [F], 2.1, [0.60], seen_z=[0.61])
    assert ev.codes.tolist() == [PLACE]


def test_no_pick_for_what_never_rested_and_releases_are_final():
    h = empty_holds((2,))
    # object 0 first seen in the air (never rested): held, no Pick; object 1 rested, then picked
    h = step(h, [F, F], [F, F], [F, F], 0.1, [1.0, 0.7], resting=[False, True]).holds
    ev = step(h, [F, F], [H, H], [H, H], 0.2, [1.0, 0.7])
    assert ev.codes.tolist() == [NO_EVENT, PICK]
    # both let go in the air in view (Release at once, no wait), then the unseen release of another
    ev2 = step(ev.holds, [H, H], [H, H], [F, F], 1.0, [1.0, 0.9], supported=[False, False], resting=[False, False])
    assert ev2.codes.tolist() == [RELEASE, RELEASE] and np.all(np.isnan(ev2.holds[:, LET_GO_T]))
    ev3 = step(ev.holds, [F, F], [F, F], [F, F], 1.0, [1.0, 0.9], release=[PLACE, 0])
    assert ev3.codes.tolist() == [PLACE, NO_EVENT]


def test_episode_rule_checks_its_values():
    with pytest.raises(ValueError):
        EpisodeRule(lift=0.0)
    with pytest.raises(ValueError):
        EpisodeRule(smoothing=1.5)


def test_a_let_go_is_dated_when_given_but_never_before_its_pick():
    h = empty_holds((2,))
    h = step(h, [F, F], [F, F], [F, F], 0.1, [0.7, 0.7]).holds
    h = step(h, [F, F], [H, H], [H, H], 1.0, [0.7, 0.7], pick_t=[0.9, 0.9]).holds
    m = 2
    ev = update_events(h, np.zeros(m, bool), np.zeros(m, bool), Switches(
        np.array([H, H], np.int8), np.array([H, H], np.int8), np.array([F, F], np.int8), np.zeros(m, np.int8),
        np.ones(m, bool), np.zeros(m, bool), np.full(m, 0.75), np.full(m, 0.75), np.full(m, np.nan), np.full(m, 1.5),
        let_go_t=np.array([1.2, 0.5])), 1.5, RULE)
    assert ev.holds[:, LET_GO_T].tolist() == [1.2, 0.9]


def test_the_quick_path_of_a_scene_at_rest_matches_the_full_one():
    rng = np.random.default_rng(7)
    h = empty_holds((3, 4))
    h[..., REF_Z] = rng.uniform(0.6, 0.8, (3, 4))
    h[0, 1, REF_Z] = np.nan
    z = rng.uniform(0.6, 0.8, (3, 4))
    resting = rng.uniform(size=(3, 4)) > 0.5
    free = np.zeros((3, 4), np.int8)
    quick = update_events(h, np.zeros((3, 4), bool), np.zeros((3, 4), bool), Switches(
        free, free, free, np.zeros((3, 4), np.int8), np.ones((3, 4), bool), resting, z, z, np.full((3, 4), np.nan),
        np.full((3, 4), 1.0)), 1.0, RULE)
    assert np.all(quick.codes == 0) and np.all(np.isnan(quick.times))
    assert np.array_equal(quick.holds[..., REF_Z], np.where(resting, z, h[..., REF_Z]), equal_nan=True)
    # the same through the full path (a held object elsewhere forces it): identical for these objects
    h2 = np.concatenate([h, empty_holds((3, 1))], axis=1)
    held = np.zeros((3, 5), np.int8)
    held[:, 4] = HELD
    full = update_events(h2, np.zeros((3, 5), bool), np.zeros((3, 5), bool), Switches(
        held, held, held, np.zeros((3, 5), np.int8), np.ones((3, 5), bool),
        np.append(resting, np.zeros((3, 1), bool), axis=1), np.append(z, np.ones((3, 1)), axis=1),
        np.append(z, np.ones((3, 1)), axis=1), np.full((3, 5), np.nan), np.full((3, 5), 1.0)), 1.0, RULE)
    assert np.array_equal(full.holds[:, :4], quick.holds, equal_nan=True) and np.all(full.codes[:, :4] == 0)


def test_what_a_held_object_carries_gets_no_event():
    h = empty_holds((2,))
    h = step(h, [F, F], [F, F], [F, F], 0.1, [0.70, 0.66]).holds  # a crate, and a ball resting in it
    # the crate is picked; the ball, in it, diverges too: held, silently
    ev = step(h, [F, F], [H, H], [H, H], 1.0, [0.70, 0.66], carried=[False, True])
    assert ev.codes.tolist() == [PICK, NO_EVENT] and ev.holds[1, PICK_T] == -np.inf
    # both put down: the crate is placed, the ball's let-go is no event
    ev = step(ev.holds, [H, H], [H, H], [H, H], 1.5, [0.80, 0.76])
    ev = step(ev.holds, [H, H], [H, H], [F, F], 2.0, [0.70, 0.66], resting=[False, False])
    ev = step(ev.holds, [F, F], [F, F], [F, F], 2.1, [0.70, 0.66])
    assert ev.codes.tolist() == [PLACE, NO_EVENT]


def test_carried_are_the_objects_in_or_on_a_held_one():
    is_in = np.zeros((2, 3, 3), bool)
    on_top = np.zeros((2, 3, 4), bool)
    is_in[:, 1, 0] = True        # the ball is in the crate
    on_top[:, 2, 3] = True       # the cup stands on the floor
    on_top[1, 0, 2] = True       # particle 1: the crate stands on the cup (why not)
    modes = np.array([[H, F, F], [F, F, H]], np.int8)
    assert carried(is_in, on_top, modes).tolist() == [[False, True, False], [True, False, False]]


def test_a_release_before_physics_takes_the_time_it_is_given():
    # object 0 let go out of view back at 1.4 s (behind cover), object 1 at this update
    h = step(empty_holds((2,)), [F, F], [F, F], [F, F], 0.1, [0.7, 0.7]).holds
    h = step(h, [F, F], [H, H], [H, H], 1.0, [0.7, 0.7]).holds
    ev = update_events(h, np.zeros(2, bool), np.zeros(2, bool), Switches(
        np.array([F, F], np.int8), np.array([F, F], np.int8), np.array([F, F], np.int8),
        np.array([RELEASE, RELEASE], np.int8), np.zeros(2, bool), np.zeros(2, bool), np.full(2, 0.9), np.full(2, 0.9),
        np.full(2, np.nan), np.full(2, 2.0), release_t=np.array([1.4, np.nan])), 2.0, RULE)
    assert ev.codes.tolist() == [RELEASE, RELEASE]
    assert ev.times[0] == 1.4 and np.isnan(ev.times[1])  # NaN: at the update


def test_held_and_let_fall_in_one_update_was_never_held():
    """A free object that physics switches to HELD (it diverged) and the Release rule lets fall in
    the same update rolled off an edge: no Pick, no Release. A held one let fall is a Release."""
    h = empty_holds((2,))
    h = step(h, [F, F], [F, F], [F, F], 0.1, [0.70, 0.70]).holds
    h = step(h, [F, F], [F, H], [F, H], 1.0, [0.70, 0.70], pick_t=[1.0, 0.9]).holds  # object 1 picked
    ev = step(h, [F, H], [H, H], [F, F], 1.1, [0.60, 0.75], supported=[False, False], resting=[False, False])
    assert ev.codes.tolist() == [NO_EVENT, RELEASE] and ev.modes.tolist() == [F, F]


def test_a_held_object_let_fall_off_the_edge_it_rolled_to_was_pushed():
    """Held along the table since a Pick at 0.9 s, objects 0 and 1 fall off its edge (rolled_off),
    object 2 falls elsewhere: 0 was pushed (a Push at the Pick's time); 1, lifted 5 cm while held,
    and 2 were dropped (Release). The fall in this update is no lift."""
    h = empty_holds((3,))
    h = step(h, [F, F, F], [F, F, F], [F, F, F], 0.1, [0.70] * 3).holds
    h = step(h, [F, F, F], [H, H, H], [H, H, H], 1.0, [0.70] * 3, pick_t=[0.9] * 3).holds
    h = step(h, [H, H, H], [H, H, H], [H, H, H], 1.1, [0.705, 0.75, 0.705]).holds
    fall = dict(supported=[False] * 3, resting=[False] * 3)
    ev = step(h, [H, H, H], [H, H, H], [F, F, F], 1.2, [0.62, 0.62, 0.62], rolled_off=[True, True, False], **fall)
    assert ev.codes.tolist() == [PUSH, RELEASE, RELEASE]
    assert ev.times[0] == 0.9 and np.isnan(ev.times[1:]).all()
    plain = step(h, [H, H, H], [H, H, H], [F, F, F], 1.2, [0.62, 0.62, 0.62], **fall)
    assert plain.codes.tolist() == [RELEASE, RELEASE, RELEASE]
