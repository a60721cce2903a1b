"""estimator.model.hidden: where held objects were out of view, and how they were let go there."""
import numpy as np

from actions.modes import FREE, HELD, PLACE, ModePriors


def test_where_a_held_object_last_rested_out_of_view_is_kept_until_it_starts_again():
    from estimator.model.hidden import resting_place

    K, M = 2, 1
    at, tt = np.zeros((K, M, 3)), np.full((K, M), -np.inf)
    none = np.zeros((K, M), bool)
    poses = np.zeros((K, M, 7))
    for j, (sup, hidden) in enumerate([([False, True], True), ([True, False], True), ([False, False], True),
                                       ([True, True], False)]):
        poses[..., 2] = 0.7 + 0.1 * j
        at, tt = resting_place(at, tt, poses, np.full((K, M), hidden), np.array(sup)[:, None], none, float(j))
    assert list(tt[:, 0]) == [1.0, 0.0] and np.allclose(at[:, 0, 2], [0.8, 0.7])  # in view (the last): not taken
    at, tt = resting_place(at, tt, poses, none, none, np.array([[True], [False]]), 5.0)
    assert list(tt[:, 0]) == [-np.inf, 0.0]


def test_a_held_object_set_down_out_of_view_is_let_go_when_its_hand_lifts_away():
    """Held in a tracked hand out of view, having rested on a support at 0.70 m: once the hand carries
    it more than carry_distance above that place (and only at that crossing), ``put_down_touched`` of
    4000 particles let it go (4 binomial standard errors); not where it never rested, nor before the
    hand rose, nor after the crossing, nor without a tracked hand; let go where it rested, a Place."""
    from types import SimpleNamespace

    from estimator.model.hidden import let_go_where_rested, set_down_behind_cover

    priors = ModePriors(put_down_touched=0.8, carry_distance=0.05)
    K = 4000
    modes = np.full((K, 1), HELD, np.int8)
    rest_at = np.zeros((K, 1, 3))
    rest_at[..., 2] = 0.70
    rest_t = np.full((K, 1), 2.0)
    rest_t[:1000] = -np.inf
    before = np.full((K, 1), 0.72)
    rng = np.random.default_rng(9)
    let = set_down_behind_cover(modes, rest_at, rest_t, before, np.array([0.80]), np.array([True]), priors, rng)
    assert not let[:1000].any()
    assert abs(let[1000:].mean() - 0.8) < 4 * np.sqrt(0.8 * 0.2 / 3000)
    for hand_z, b, tracked in ((0.74, 0.72, True), (0.80, 0.78, True), (0.80, 0.72, False), (np.nan, 0.72, True)):
        none = set_down_behind_cover(modes, rest_at, rest_t, np.full((K, 1), b), np.array([hand_z]),
                                     np.array([tracked]), priors, rng)
        assert not none.any(), (hand_z, b, tracked)
    poses, vel, codes = np.ones((K, 1, 7)), np.ones((K, 1, 6)), np.zeros((K, 1), np.int8)
    when = let_go_where_rested(let, SimpleNamespace(rest_at=rest_at, rest_t=rest_t), poses, vel, modes, codes)
    assert np.all(modes[let] == FREE) and np.all(codes[let] == PLACE) and np.all(vel[let] == 0)
    assert np.all(poses[let, 2] == 0.70) and np.all(when[let] == 2.0) and np.all(np.isnan(when[~let]))
    assert np.all(modes[~let] == HELD) and np.all(poses[~let] == 1)


def test_hidden_places_are_a_uniform_sample_over_the_hidden_updates():
    """Reservoir sampling: after n hidden updates each of them is the sample with probability 1/n
    (a binomial band over many particles); a reset entry starts again; visible updates never count."""
    from estimator.model.hidden import hidden_places

    K, M, n = 4000, 1, 5
    rng = np.random.default_rng(7)
    at, tt, cnt = np.zeros((K, M, 3)), np.full((K, M), -np.inf), np.zeros((K, M), np.int32)
    none = np.zeros((K, M), bool)
    for j in range(n):
        poses = np.zeros((K, M, 7))
        poses[..., 0] = j  # the hand's place at update j
        at, tt, cnt = hidden_places(at, tt, cnt, poses, ~none, none, float(j), rng)
        # a visible update in between changes nothing
        at, tt, cnt = hidden_places(at, tt, cnt, poses + 100.0, none, none, j + 0.5, rng)
    assert np.all(cnt == n) and set(np.unique(at[..., 0])) <= set(range(n)) and np.all(at[..., 0] == tt)
    counts = np.bincount(at[:, 0, 0].astype(int), minlength=n)
    band = 3 * np.sqrt(K * (1 / n) * (1 - 1 / n))
    assert np.all(np.abs(counts - K / n) <= band)
    at2, tt2, cnt2 = hidden_places(at, tt, cnt, poses, none, ~none, 9.0, rng)
    assert np.all(cnt2 == 0) and np.array_equal(at2, at)  # the sample is kept, the count restarts


def test_the_lowest_hidden_place_is_kept_with_its_time():
    """Where (and when) the held object was lowest over its hidden updates, counted by
    :func:`hidden_places`; visible updates do not count; a reset entry starts again, its first
    hidden update then taken whatever its height."""
    from estimator.model.hidden import hidden_places, lowest_hidden_place

    K, M = 2, 1
    rng = np.random.default_rng(3)
    at, tt, cnt = np.zeros((K, M, 3)), np.full((K, M), -np.inf), np.zeros((K, M), np.int32)
    low, low_t = np.zeros((K, M, 3)), np.full((K, M), -np.inf)
    none = np.zeros((K, M), bool)

    def update(poses, hidden, reset, t):
        nonlocal at, tt, cnt, low, low_t
        low, low_t = lowest_hidden_place(low, low_t, cnt, poses, hidden, t)
        at, tt, cnt = hidden_places(at, tt, cnt, poses, hidden, reset, t, rng)

    heights = [[0.9, 0.7, 0.8, 0.75], [0.9, 1.0, 0.95, 0.6]]  # per particle, over four hidden updates
    for j in range(4):
        poses = np.zeros((K, M, 7))
        poses[:, 0, 2] = [h[j] for h in heights]
        poses[:, 0, 0] = j
        update(poses, ~none, none, float(j))
        update(poses - 5.0, none, none, j + 0.5)  # in view: lower, ignored
    assert list(low[:, 0, 2]) == [0.7, 0.6] and list(low_t[:, 0]) == [1.0, 3.0] and list(low[:, 0, 0]) == [1.0, 3.0]
    assert np.all(cnt == 4)
    update(poses, none, ~none, 9.0)
    assert np.all(cnt == 0)
    poses[:, 0, 2] = 2.0  # higher than the kept place, but the first hidden update after the reset
    update(poses, ~none, none, 10.0)
    assert np.all(low[:, 0, 2] == 2.0) and np.all(low_t == 10.0)


def test_release_behind_cover_draws_from_the_posterior_and_weighs_the_move():
    """Among held objects whose hand shows in view without them for the first time, the share let go
    is r / (r + (1 - r) L) within a binomial band, and every candidate gets the factor
    (r + (1 - r) L) / L; others are untouched; hand_occlusion = 1 (the paper) does nothing."""
    from dataclasses import replace

    from estimator.config import NoiseConfig
    from estimator.model.hidden import release_behind_cover

    K, M = 5000, 2
    noise, priors = NoiseConfig(), ModePriors()
    modes = np.full((K, M), HELD, np.int8)
    unseen = np.array([[1, 2]] * K, np.int32)  # object 1 was already in view before: no second chance
    hidden_n = np.full((K, M), 3, np.int32)
    hidden_n[: K // 2, 0] = 0  # half never hidden: nowhere to have let it go
    cover, logw = release_behind_cover(modes, unseen, hidden_n, np.array([True, True]), priors, noise,
                                       np.random.default_rng(3))
    h, r = noise.hand_occlusion, priors.release_hidden
    L = h + (1 - h) * noise.miss_prob
    p = r / (r + (1 - r) * L)
    cand = K - K // 2
    assert not cover[: K // 2].any() and not cover[:, 1].any()
    assert abs(cover[:, 0].sum() - p * cand) <= 3 * np.sqrt(cand * p * (1 - p))
    assert np.allclose(logw[K // 2:], np.log((r + (1 - r) * L) / L)) and np.all(logw[: K // 2] == 0)
    none, zero = release_behind_cover(modes, unseen, hidden_n, np.array([True, True]), priors,
                                      replace(noise, hand_occlusion=1.0), np.random.default_rng(3))
    assert not none.any() and np.all(zero == 0)
