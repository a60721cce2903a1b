import numpy as np
import pytest

from actions.modes import (
    EVENT_NAMES,
    FREE,
    HELD,
    MODES,
    NO_EVENT,
    PICK,
    PLACE,
    PUSH,
    RELEASE,
    ModePriors,
    is_free,
    is_held,
    merge_events,
    switch_events,
)


def test_mode_registry_answers_who_moves_an_object_for_any_shape():
    assert [int(m.code) for m in MODES] == list(range(len(MODES)))
    assert [m.name for m in MODES] == ["free", "held"]
    modes = np.array([[FREE, HELD, HELD], [HELD, FREE, FREE]], dtype=np.int8)
    assert is_held(modes).tolist() == [[False, True, True], [True, False, False]]
    assert is_free(modes).tolist() == (~is_held(modes)).tolist()
    assert is_held(modes).dtype == bool and is_held(modes[:, 1]).shape == (2,)
    assert bool(is_held(HELD)) and bool(is_free(FREE)) and not bool(is_held([FREE])[0])


def test_switch_events_labels():
    prev = np.array([FREE, HELD, HELD, FREE, HELD])
    new = np.array([HELD, FREE, FREE, FREE, HELD])
    supported = np.array([True, True, False, True, False])
    assert switch_events(prev, new, supported).tolist() == [PICK, PLACE, RELEASE, NO_EVENT, NO_EVENT]
    # batched (K, M) with the support mask broadcast over particles
    k = switch_events(np.stack([prev, prev]), np.stack([new, prev]), supported)
    assert k.shape == (2, 5) and k[1].tolist() == [0] * 5
    merged = merge_events(np.array([0, PICK, 0]), np.array([RELEASE, PLACE, 0]))
    assert merged.tolist() == [RELEASE, PICK, 0]


def test_priors_costs():
    pr = ModePriors(pick=0.1, place=0.3)
    prev = np.array([FREE, FREE, HELD, HELD, HELD])
    new = np.array([HELD, FREE, FREE, HELD, FREE])
    seen = np.array([True, True, True, True, False])
    c = pr.log_prior_cost(prev, new, seen)
    assert np.allclose(c, np.log([0.1, 0.9, 0.3, 0.7, 1.0]))
    with pytest.raises(ValueError):
        ModePriors(pick=1.5)


def test_event_codes_name_the_four_actions_in_column_order():
    assert EVENT_NAMES == {PICK: "Pick", PLACE: "Place", RELEASE: "Release", PUSH: "Push"}
    assert sorted(EVENT_NAMES) == list(range(1, len(EVENT_NAMES) + 1))  # code - 1 is the column
    # a switch is never a Push by itself: it is a Place until the hold record says otherwise
    assert PUSH not in switch_events(np.array([HELD, FREE]), np.array([FREE, HELD]), True)
