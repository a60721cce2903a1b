"""Held objects in the scene model (estimator/model/holding.py): release at loss by hand state, targets."""
import numpy as np

from actions.modes import FREE, HELD
from actions.push import AIRBORNE, PICK_T, REF_Z, SMOOTH_Z, TOP_Z, empty_holds
from estimator.model.holding import push_grips, pushes_ended, slide_around_hand, stratified_uniforms


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
