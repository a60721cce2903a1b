"""Held objects in the scene model (estimator/model/holding.py): release at loss by hand state, targets."""
import numpy as np

from actions.modes import FREE, HELD, PLACE, ModePriors
from actions.push import AIRBORNE, PICK_T, REF_Z, SMOOTH_Z, TOP_Z, empty_holds
from estimator.config import ReasonerConfig
from estimator.model.holding import push_grips, pushes_ended, slide_around_hand, stratified_uniforms
from estimator.model.mechanisms.release import release_on_loss
from estimator.model import initial_poses
from estimator.observations import Detection, Frame
from estimator.model.perception_memory import PerceptionMemory
from physics.scene import scene_from_dict


def _memory(hand_end):
    sc = scene_from_dict({"objects": [{"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08},
                                       "pose": {"position": [0.1, 0.0, 0.04]}}]})
    mem = PerceptionMemory(sc, initial_poses(sc)[0], ReasonerConfig(), True)
    mem.record(Frame(0.0, {"cup": Detection(np.array([0.1, 0.0, 0.7]))}, {"h": np.array([0.1, 0.0, 0.78])}))
    for k in range(1, 4):
        mem.record(Frame(0.1 * k, {}, {"h": np.array(hand_end)}))
    mem.perceived_prev = np.array([True])
    return mem


def test_the_share_released_at_loss_follows_the_hand_state():
    """4000 particles: the released share is within 4 binomial standard errors of the prior of the
    hand's state (carried 0.1, still 0.6); nothing is released while the object is perceived."""
    priors = ModePriors(release_on_loss_carried=0.1, release_on_loss_still=0.6, carry_distance=0.05)
    K = 4000
    modes = np.full((K, 1), HELD, np.int8)
    for hand_end, p in (([0.4, 0.0, 0.78], 0.1), ([0.11, 0.0, 0.78], 0.6)):
        new, codes = release_on_loss(modes, np.array([False]), np.zeros((K, 1), bool), np.random.default_rng(3),
                                     _memory(hand_end), priors, np.array([True]))
        share = np.mean(new[:, 0] == FREE)
        assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / K), (hand_end, share)
        assert np.all((codes != 0) == (new == FREE))
    new, _ = release_on_loss(modes, np.array([True]), np.zeros((K, 1), bool), np.random.default_rng(3),
                             _memory([0.4, 0.0, 0.78]), priors, np.array([True]))
    assert np.all(new == HELD)


def test_stratified_draws_let_go_k_p_particles_and_each_one_with_probability_p():
    """Each column lets go floor(K p) or ceil(K p) particles (64 particles at the carried prior
    0.024: 1 or 2, where independent draws give 1.5 +- 1.2); each particle is let go with probability p
    (over 4000 seeds, within 4 binomial standard errors)."""
    K, p, n = 64, 0.024, 4000
    counts, first = [], []
    for seed in range(n):
        u = stratified_uniforms(K, 3, np.random.default_rng(seed))
        assert u.shape == (K, 3) and np.all((u >= 0) & (u < 1))
        counts += list((u < p).sum(axis=0))
        first.append(u[0, 1] < p)
    assert set(counts) <= {int(np.floor(K * p)), int(np.ceil(K * p))}
    assert abs(np.mean(first) - p) < 4 * np.sqrt(p * (1 - p) / n)
    assert abs(np.mean(counts) - K * p) < 4 * 0.5 / np.sqrt(len(counts))  # the count's mean is K p


def test_a_held_object_that_leaves_view_in_motion_is_let_go_in_every_particle():
    """Seen moving along its support at the last update, undetected now, no tracked hand (``left_view``):
    every particle that holds it lets it go, though it still counts as perceived; the switch is a
    Place (on a support); without ``left_view`` nothing is let go while perceived."""
    K = 100
    modes = np.full((K, 1), HELD, np.int8)
    modes[:10] = FREE
    mem = _memory([0.1, 0.0, 0.78])
    supported = np.ones((K, 1), bool)
    new, codes = release_on_loss(modes, np.array([True]), supported, np.random.default_rng(5), mem, ModePriors(),
                                 None, np.array([True]))
    assert np.all(new == FREE) and np.all(codes[10:] == PLACE) and np.all(codes[:10] == 0)
    kept, _ = release_on_loss(modes, np.array([True]), supported, np.random.default_rng(5), mem, ModePriors(), None,
                              np.array([False]))
    assert np.array_equal(kept, modes)


def test_where_a_held_object_last_rested_out_of_view_is_kept_until_it_starts_again():
    from estimator.model.holding import resting_place

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

    from estimator.model.holding import let_go_where_rested, set_down_behind_cover

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
    from estimator.model.holding import hidden_places

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
    from estimator.model.holding import hidden_places, lowest_hidden_place

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
    from estimator.model.holding import release_behind_cover

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


def test_a_push_ends_when_the_hand_rises_off_an_unlifted_object():
    """pushes_ended: held, never lifted (its record's top no higher than its rest plus lift), in a
    tracked hand, undetected, and the hand now 3 cm above where the particle has it: let go. A lifted
    episode, a free object, a hand still at its height, or no hand: not."""
    K, M = 4, 2
    holds = empty_holds((K, M))
    holds[..., PICK_T] = 1.0
    holds[..., REF_Z] = 0.66
    holds[..., SMOOTH_Z] = holds[..., TOP_Z] = 0.665
    holds[..., AIRBORNE] = 0
    holds[1, 0, TOP_Z] = 0.72  # that particle's episode lifted it
    modes = np.full((K, M), HELD, np.int8)
    modes[2, 0] = FREE
    before = np.full((K, M), 0.665)
    hand_z = np.array([0.695, 0.67])  # object 0's hand rose 3 cm, object 1's did not
    ended = pushes_ended(modes, holds, before, hand_z, np.array([True, True]), 0.02)
    assert ended[:, 0].tolist() == [True, False, False, True] and not ended[:, 1].any()
    assert not pushes_ended(modes, holds, before, hand_z, np.array([False, True]), 0.02).any()
    assert not pushes_ended(modes, holds, before, np.array([np.nan, np.nan]), np.array([True, True]), 0.02).any()


def _pushed_by_steps(offset, travel, steps=20000):
    """A frictionless round hand pushing a round object in small steps: at each step the hand moves
    along ``travel``; where it comes nearer than the contact radius the object is pushed out along
    the line of their centres (a contact cannot pull). Independent of the closed form. Returns the
    object's offset to the hand at the end (horizontal) and the hand's travel when they parted."""
    radius = float(np.hypot(*offset[:2]))
    hand, obj = np.zeros(2), np.array(offset[:2], dtype=float)
    step = np.asarray(travel[:2], dtype=float) / steps
    parted = None
    for i in range(steps):
        hand = hand + step
        d = obj - hand
        dist = float(np.hypot(*d))
        if dist < radius:
            obj = hand + d / dist * radius
        elif parted is None and dist > radius + 1e-9:
            parted = (i + 1) * float(np.hypot(*step))
    return obj - hand, parted


def test_a_frictionless_push_slides_around_the_hand_as_a_contact_does():
    """grip 1 is the frictionless contact: the offsets of slide_around_hand agree with a hand pushing
    in 20000 small steps (to 1 mm) while they touch, and contact is lost where the stepped object
    parts from the hand (to 2 mm of travel), the object then beside the hand's path at the contact
    radius; grip 0 drags the object along at its offset; a hand moving away pushes nothing (lost,
    left where it is: NaN); travel within the noise changes nothing."""
    offset = np.array([[0.02, 0.07, 0.01], [-0.005, 0.076, 0.0]])
    for s in (0.05, 0.1):
        out, lost, at = slide_around_hand(offset, np.array([0.0, s, 0.0]), np.ones(2), 0.01)
        assert not lost.any() and np.all(np.isnan(at))
        for j in range(2):
            stepped, parted = _pushed_by_steps(offset[j], np.array([0.0, s]))
            assert parted is None and np.allclose(out[j, :2], stepped, atol=1e-3), (s, j, out[j], stepped)
        assert np.allclose(out[:, 2], offset[:, 2])
        assert np.allclose(np.hypot(out[:, 0], out[:, 1]), np.hypot(offset[:, 0], offset[:, 1]))
    travel = np.array([0.0, 0.3, 0.0])
    out, lost, at = slide_around_hand(offset, travel, np.ones(2), 0.01)
    assert lost.all()
    for j in range(2):
        _, parted = _pushed_by_steps(offset[j], travel[:2])
        s_loss = at[j, 1]  # along the travel (+y): where the hand was when it parted
        assert abs(s_loss - parted) < 2e-3, (j, s_loss, parted)
        assert abs(abs(at[j, 0]) - np.hypot(*offset[j, :2])) < 1e-9  # beside the path at the radius
        assert np.sign(at[j, 0]) == np.sign(offset[j, 0]) and at[j, 2] == offset[j, 2]
    # half the grip: the same angle after twice the travel
    half, _, _ = slide_around_hand(offset, np.array([0.0, 0.2, 0.0]), np.full(2, 0.5), 0.01)
    full, _, _ = slide_around_hand(offset, np.array([0.0, 0.1, 0.0]), np.ones(2), 0.01)
    assert np.allclose(half, full)
    same, lost, _ = slide_around_hand(offset, travel, np.zeros(2), 0.01)
    assert np.allclose(same, offset) and not lost.any()
    _, lost, at = slide_around_hand(offset, -travel, np.ones(2), 0.01)
    assert lost.all() and np.all(np.isnan(at))
    same, lost, _ = slide_around_hand(offset, np.array([0.0, 0.005, 0.0]), np.ones(2), 0.01)
    assert np.allclose(same, offset) and not lost.any()


def test_push_grips_are_drawn_once_per_push_out_of_view_and_forgotten_on_detection():
    """Entries pushed out of view without a grip draw one (uniform: over 4000 columns of 64 the share
    below 0.3 is within 4 binomial standard errors of 0.3, and each column is stratified); a grip
    already drawn is kept; a detected object's grips are forgotten; with nothing to draw no random
    number is used."""
    K, M = 64, 4000
    rng = np.random.default_rng(7)
    grip = np.full((K, M), np.nan)
    pushed = np.ones((K, M), dtype=bool)
    g = push_grips(grip, pushed, np.zeros(M, dtype=bool), rng)
    assert np.all((g >= 0) & (g < 1))
    assert abs(np.mean(g < 0.3) - 0.3) < 4 * np.sqrt(0.3 * 0.7 / (K * M))
    assert set(np.unique((g < 0.3).sum(axis=0))) <= {19, 20}
    detected = np.zeros(M, dtype=bool)
    detected[:10] = True
    again = push_grips(g, pushed & ~detected[None, :], detected, rng)
    assert np.all(np.isnan(again[:, :10])) and np.array_equal(again[:, 10:], g[:, 10:])
    state = rng.bit_generator.state
    kept = push_grips(g, pushed, np.zeros(M, dtype=bool), rng)
    assert np.array_equal(kept, g) and rng.bit_generator.state == state
