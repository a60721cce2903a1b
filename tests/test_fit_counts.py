"""Counting the held-object priors' samples on one run: losses (carried / still, let go hidden, put
down), offsets of held objects from the estimator's memory, set-downs out of view, detections out of
reach, descents, accelerations and hand occlusions, on hand-built streams (the simulator's line
format)."""
from types import SimpleNamespace

import numpy as np
import pytest

from actions.modes import ModePriors
from estimator.config import EstimatorConfig, HandConfig, ReasonerConfig
from experiments.evaluation.fit_counts import (
    Counts,
    Spread,
    count_accelerations,
    count_descents,
    count_losses,
    count_offsets,
    count_out_of_reach,
    count_set_downs,
)
from experiments.evaluation.fit_priors import best_threshold
from physics.scene import scene_from_dict


def _stream(hand_path, seen_until, held_until, t_end=2.0, dt=0.05, rest_z=None):
    """Observation and truth lines: the cup 8 cm under the hand, detected until ``seen_until`` s, held
    in truth until ``held_until`` s (then it stays where it was let go, or falls to ``rest_z``)."""
    obs, truth = [], []
    for t in np.arange(0.0, t_end, dt):
        hand = np.asarray(hand_path(t), float)
        held = t < held_until
        cup = hand - [0, 0, 0.08] if held else np.asarray(hand_path(held_until)) - [0, 0, 0.08]
        if not held and rest_z is not None:
            cup[2] = rest_z
        o = {"t": float(t), "objects": {}, "hands": {"human/right": hand.tolist()}}
        if t < seen_until:
            o["objects"]["cup"] = {"position": cup.tolist()}
        obs.append(o)
        truth.append({"t": float(t), "objects": {"cup": {"position": cup.tolist(), "held": held, "visible": True}}})
    return obs, truth


def test_losses_are_counted_as_carried_or_still_with_their_outcome():
    r, pr = ReasonerConfig(), ModePriors(carry_distance=0.05)
    carried, still = Counts(), Counts()
    obs, truth = _stream(lambda t: [0.3 * t, 0.0, 1.0], seen_until=0.5, held_until=9.0)  # carried on
    count_losses(obs, truth, r, pr, carried, still)
    assert (carried.hits, carried.n, still.n) == (0, 1, 0)
    obs, truth = _stream(lambda t: [0.3, 0.0, 1.0], seen_until=0.5, held_until=0.5)  # still hand, let go
    count_losses(obs, truth, r, pr, carried, still)
    assert (still.hits, still.n, carried.n) == (1, 1, 1)
    assert carried.p == pytest.approx(1 / 3) and still.p == pytest.approx(2 / 3)  # Laplace's rule
    assert Counts().p == 0.5


def test_carried_losses_let_go_before_being_seen_again_count_for_release_hidden():
    r, pr = ReasonerConfig(), ModePriors(carry_distance=0.05)
    carried, still, hidden, put_down = Counts(), Counts(), Counts(), Counts()
    carry = lambda t: [0.3 * t, 0.0, 1.0]  # noqa: E731
    obs, truth = _stream(carry, seen_until=0.5, held_until=1.6)  # carried out of view, put down at 1.6 s
    count_losses(obs, truth, r, pr, carried, still, hidden, put_down)
    obs, truth = _stream(carry, seen_until=0.5, held_until=9.0)  # carried on to the end
    count_losses(obs, truth, r, pr, carried, still, hidden, put_down)
    obs, truth = _stream(carry, seen_until=0.5, held_until=1.2, rest_z=0.04)  # dropped to the floor at 1.2 s
    count_losses(obs, truth, r, pr, carried, still, hidden, put_down)
    assert (hidden.hits, hidden.n) == (2, 3) and (carried.hits, carried.n) == (0, 3)
    assert (put_down.hits, put_down.n) == (1, 2)  # of the two let go, one put down, one dropped


def _noisy_carry(hand_std: float, seed: int):
    """A cup carried 8 cm under a hand at 0.3 m/s for 3 s at 30 frames/s, detected (exactly) for
    the first 1.5 s; the tracked hand is ``hand_std`` (m per axis) off in every frame."""
    rng = np.random.default_rng(seed)
    obs, truth = _stream(lambda t: [0.3 * t, 0.0, 1.0], seen_until=1.5, held_until=9.0, t_end=3.0, dt=1 / 30)
    for o, row in zip(obs, truth):
        row["hands"] = {"human/right": list(o["hands"]["human/right"])}
        o["hands"]["human/right"] = (np.asarray(o["hands"]["human/right"]) + rng.normal(0, hand_std, 3)).tolist()
    scene = scene_from_dict({"name": "carry", "objects": [
        {"id": "cup", "box": {"size": [0.05, 0.05, 0.08]}, "pose": {"position": [0, 0, 0.04]}}]})
    return SimpleNamespace(scene=scene, observations=obs, truth=truth)


def test_offsets_are_measured_where_the_estimators_memory_puts_held_objects():
    """Exact hands: the memory puts the hidden cup exactly at the hand + offset (spread 0). Noisy
    hands (1 cm per axis): the tracked hand's error is measured (its std within 3 standard errors of
    1 cm), and the filtered hand and averaged offset put the cup closer than raw frames do."""
    exact = _noisy_carry(0.0, 0)
    spread = Spread()
    count_offsets(exact, EstimatorConfig(), spread)
    assert spread.n == 45 and spread.std == pytest.approx(0.0, abs=1e-6)
    filtered, raw, hand = Spread(), Spread(), Spread()
    for seed in range(1, 9):  # the offset's error is shared by a run's frames: eight runs
        noisy = _noisy_carry(0.01, seed)
        count_offsets(noisy, EstimatorConfig(), filtered, hand)
        count_offsets(noisy, EstimatorConfig(hands=HandConfig(filtered=False)), raw)
    assert hand.n == 8 * 90 and abs(hand.std - 0.01) < 3 * 0.01 / np.sqrt(2 * 3 * hand.n)
    # raw: the hand now and the hand at the last detection, each 1 cm off: about 1.4 cm per axis
    # (its estimate from 8 x 3 offset errors and 360 x 3 frame errors: about 0.1 cm standard error)
    assert raw.std > 0.011 and filtered.std < 0.8 * raw.std


def test_set_downs_out_of_view_are_counted_when_the_hand_lifts_away():
    """Out of view, the held cup rests on the table (a truth relation) while the hand is at 0.8 m;
    once the hand is more than carry_distance higher, the sample is whether the cup is still held.
    One sample per stretch out of view; no sample without a rest or without the rise."""
    pr = ModePriors(carry_distance=0.05)

    def stream(hand_z, held_until, rests_from=0.5):
        obs, truth = [], []
        for t in np.arange(0.0, 2.0, 0.05):
            hand = [0.0, 0.0, float(hand_z(t))]
            held = t < held_until
            obs.append({"t": float(t), "objects": {} if t >= 0.2 else {"cup": {"position": [0, 0, 0.7]}},
                        "hands": {"h": hand}})
            rel = [{"subject": "cup", "predicate": "isOnTop", "object": "table", "p": 1.0}] if t >= rests_from else []
            truth.append({"t": float(t), "objects": {"cup": {"held": held}}, "relations": rel})
        return obs, truth

    lift = lambda t: 0.8 if t < 1.0 else 0.8 + 0.2 * (t - 1.0)  # noqa: E731  (rises from 1 s)
    touched = Counts()
    count_set_downs(*stream(lift, held_until=0.9), pr, touched)  # let go before the hand rose
    count_set_downs(*stream(lift, held_until=9.0), pr, touched)  # lifted again with the hand
    assert (touched.hits, touched.n) == (1, 2)
    count_set_downs(*stream(lambda t: 0.8, held_until=0.9), pr, touched)  # the hand never rises
    count_set_downs(*stream(lift, held_until=0.9, rests_from=9.0), pr, touched)  # never rests
    assert touched.n == 2


def test_held_objects_seen_out_of_reach_of_the_tracked_hands_are_counted():
    obs, truth = _stream(lambda t: [0.3 * t, 0.0, 1.0], seen_until=0.5, held_until=0.3)
    reach = Counts()
    count_out_of_reach(obs, truth, reach)
    assert (reach.hits, reach.n) == (0, 6)  # held and seen at 0, 0.05, ..., 0.25 s, 8 cm from the hand
    far = [dict(o, hands={"human/right": [5.0, 0.0, 1.0]}) for o in obs]
    count_out_of_reach(far, truth, reach)
    assert (reach.hits, reach.n) == (6, 12)
    count_out_of_reach([dict(o, hands={}) for o in obs], truth, reach)  # no hand tracked: not counted
    assert reach.n == 12


def _descent(lower_accel, drop_at, t_end=1.2, dt=1 / 30):
    """A cup held 80 cm over the floor, lowered from t = 0.1 s by a hand accelerating down at
    ``lower_accel`` (m/s^2) to 0.5 m/s, then (at ``drop_at`` s) let go: it falls freely."""
    scene = scene_from_dict({"name": "drop", "objects": [
        {"id": "cup", "box": {"size": [0.05, 0.05, 0.08]}, "pose": {"position": [0, 0, 0.04]}}]})
    obs, truth, z, v = [], [], 0.8, 0.0
    for t in np.arange(0.0, t_end, dt):
        held = t < drop_at
        if t > 0.1:
            v = max(v - (lower_accel if held else 9.81) * dt, -0.5 if held else -10.0)
            z = max(z + v * dt, 0.04)
        pos = [0.0, 0.0, z]
        obs.append({"t": float(t), "objects": {"cup": {"position": pos}}, "hands": {"h": [0, 0, z + 0.08]}})
        truth.append({"t": float(t), "objects": {"cup": {"position": pos, "held": held, "visible": True}}})
    return SimpleNamespace(scene=scene, observations=obs, truth=truth)


def test_descents_are_sampled_as_held_while_lowered_and_let_go_once_dropped():
    r = ReasonerConfig()
    held, let_go = [], []
    count_descents(_descent(3.0, drop_at=10.0), r, held, let_go)  # lowered, never let go
    assert held and not let_go
    assert max(held) < 5.0  # the hand's 3 m/s^2 (over a reasoning step, with the start of the motion)
    held, let_go = [], []
    count_descents(_descent(3.0, drop_at=0.45), r, held, let_go)  # lowered, then dropped
    assert len(let_go) == 1 and 7.0 < let_go[0] < 12.0  # free fall, seen over whole steps
    # the fitted threshold lies between them
    a, errors = best_threshold(held, let_go)
    assert errors == 0 and max(held) < a < let_go[0]


def test_accelerations_of_held_objects_are_sampled_per_axis_from_the_truth():
    """A cup held on a parabola x = a t^2 / 2 (a = 3 m/s^2) gives a on x and 0 on y and z at every
    interior row held in truth; rows next to one where it is not held give none."""
    a = 3.0
    obs, truth = _stream(lambda t: [0.5 * a * t * t, 0.0, 1.0], seen_until=2.0, held_until=1.0, t_end=1.5)
    samples = []
    count_accelerations(truth, samples)
    held_rows = sum(r["objects"]["cup"]["held"] for r in truth)
    assert len(samples) == 3 * (held_rows - 2)
    s = np.asarray(samples).reshape(-1, 3)
    np.testing.assert_allclose(s[:, 0], a, rtol=1e-6)
    np.testing.assert_allclose(s[:, 1:], 0.0, atol=1e-9)


def test_hand_occlusion_counts_held_frames_that_the_scene_alone_would_show():
    """A held cup in plain view of the camera: every held frame counts, a hit where the truth does not
    show it; a frame out of view of the scene alone (behind the camera) and a free frame do not."""
    from experiments.evaluation.fit_counts import count_hand_occlusion

    scene = scene_from_dict({"name": "occ", "camera": {"position": [1.5, 0, 1.0], "target": [0, 0, 0.3]},
                             "objects": [{"id": "cup", "box": {"size": [0.06, 0.06, 0.1]},
                                          "pose": {"position": [0, 0, 0.05]}}]})

    def row(y, visible, held=True, x=0.0):
        return {"t": 0.0, "relations": [], "objects": {"cup": {"position": [x, y, 0.3], "orientation": [0, 0, 0, 1],
                                                               "held": held, "visible": visible}}}
    truth = [row(0.0, True), row(0.02, False), row(0.04, False), row(0.0, False, held=False), row(0, False, x=3.0)]
    counts = Counts()
    count_hand_occlusion(SimpleNamespace(scene=scene, truth=truth), 0.3, counts)
    assert (counts.hits, counts.n) == (2, 3)
