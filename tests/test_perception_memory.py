"""The perception memory: detections, velocities, hands, the Place rule's rest test, tick velocities."""
import math

import numpy as np
import pytest
from scipy.stats import chi2

from estimator.config import HandConfig, ReasonerConfig
from estimator.model import initial_poses
from estimator.model.detection_noise import ONSET_FALSE_ALARM, ONSET_SIGMAS
from estimator.model.perception_memory import MOTION_ONSET, VELOCITY_WINDOW, PerceptionMemory
from estimator.observations import Detection, Frame
from physics.scene import scene_from_dict

TABLE, CUP, BALL = range(3)
NOT_HELD = np.zeros(3, dtype=bool)  # held in no particle: only objects seen moving follow their hand


def memory(follow_hands=True, reasoner=ReasonerConfig(), from_onset=True, hands=None):
    sc = scene_from_dict({"objects": [
        {"id": "table", "static": True, "box": {"size": [1.0, 1.0, 0.1]}, "pose": {"position": [0, 0, 0.05]}},
        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "pose": {"position": [0.3, 0.3, 0.14]}},
        {"id": "ball", "sphere": {"radius": 0.03}}]})
    return PerceptionMemory(sc, initial_poses(sc)[0], reasoner, follow_hands, from_onset, hands)


def det(p, q=None, std=None):
    return Detection(np.asarray(p, float), None if q is None else np.asarray(q, float), std)


def test_record_detections_velocity_and_std():
    mem = memory()
    d = mem.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.14]), "table": det([9, 9, 9])}))
    assert list(d) == [False, True, False]  # static objects' detections are ignored
    assert np.all(mem.last_pose[TABLE, :3] == [0, 0, 0.05])
    assert np.all(mem.perc_vel[CUP] == 0)  # first sighting: no velocity
    mem.record(Frame(0.1, {"cup": det([0.32, 0.3, 0.14], (0, 0, 1, 0), std=0.004)}))
    assert np.allclose(mem.perc_vel[CUP, :3], [0.2, 0.0, 0.0])  # 2 cm in 0.1 s
    assert np.all(mem.last_pose[CUP, 3:] == [0, 0, 1, 0]) and mem.last_has_orientation[CUP]
    assert mem.last_std[CUP] == 0.004 and mem.last_seen[CUP] == 0.1
    mem.record(Frame(1.0, {"cup": det([0.5, 0.3, 0.14])}))  # after a gap longer than t_perceived
    assert np.all(mem.perc_vel[CUP] == 0) and np.isnan(mem.last_std[CUP]) and not mem.last_has_orientation[CUP]
    assert np.all(mem.last_pose[CUP, 3:] == [0, 0, 1, 0])  # no orientation measured: the last one kept
    with pytest.raises(ValueError, match="unknown object id 'mug'"):
        mem.record(Frame(1.1, {"mug": det([0, 0, 0])}))


def test_perceived_within_t_perceived_and_jumps():
    mem = memory(reasoner=ReasonerConfig(t_perceived=0.5, d_perc_prev=0.03))
    mem.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.14]), "ball": det([0.0, 0.0, 0.2])}))
    assert list(mem.perceived(0.5)) == [False, True, True]
    assert list(mem.perceived(0.51)) == [False, False, False]
    # the ball was parked (unknown): its first perception is a jump; the cup moved 2 cm, less than 3
    mem.record(Frame(0.1, {"cup": det([0.32, 0.3, 0.14])}))
    assert list(mem.jumped()) == [False, False, True]
    mem.end_tick(mem.perceived(0.1), np.array([False, True, True]), np.zeros((3, 3)))
    mem.record(Frame(0.2, {"cup": det([0.36, 0.3, 0.14])}))
    assert list(mem.jumped()) == [False, True, False]  # 4 cm since the last tick


def test_nearest_tracked_hand_within_30_cm():
    mem = memory(hands=HandConfig(filtered=False))
    hands = {"human/left": np.array([1.0, 0.0, 1.0]), "human/right": np.array([0.3, 0.3, 0.34])}
    mem.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.14])}, hands))
    assert mem.hold_hand[CUP] == "human/right" and np.allclose(mem.hold_offset[CUP], [0, 0, -0.2])
    assert list(mem.following_hand(Frame(0.1, {}, hands))) == [False, True, False]
    assert list(mem.following_hand(Frame(0.1, {}, {"human/left": hands["human/left"]}))) == [False] * 3
    moved = Frame(0.1, {}, {"human/right": np.array([0.0, 0.0, 1.0])})
    mem.record(moved)
    assert np.allclose(mem.hand_target(moved, CUP), [0.0, 0.0, 0.8])
    mem.record(Frame(0.2, {"cup": det([0.3, 0.3, 0.14])}, {"human/right": np.array([0.3, 0.3, 0.45])}))
    assert mem.hold_hand[CUP] is None  # 31 cm away: not holding it
    off = memory(follow_hands=False)
    off.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.14])}, hands))
    assert off.hold_hand[CUP] == "human/right"
    assert not off.following_hand(Frame(0.1, {}, hands)).any() and off.hand_target(Frame(0.1, {}, hands), CUP) is None


def test_a_detection_from_an_earlier_frame_is_carried_on_by_its_tracked_hand():
    """An object detected in an earlier frame of the update, not in the last one, has moved on with
    its tracked hand: by the displacement of the hand's filtered position since (exact on uniform
    motion, once the filter has caught up with it); one detected in the last frame, or without a tracked hand, is at its detection; not
    one seen falling (its hand let it go)."""
    mem = memory()
    step = np.array([0.0, 0.045, 0.0])  # 1.35 m/s
    hand0 = np.array([0.3, 0.3, 0.34])
    for f in range(-40, 1):  # carried in view; the ball, far from the hand, lies still
        mem.record(Frame(f / 30, {"cup": det(hand0 + f * step - [0, 0, 0.2]), "ball": det([0.0, 0.0, 0.2])},
                         {"human/right": hand0 + f * step}))
    assert not mem.stale_in_hand(Frame(0.0, {}, {"human/right": hand0}), NOT_HELD).any()
    for f in (1, 2):  # then hidden, the hand tracked on
        mem.record(Frame(f / 30, {}, {"human/right": hand0 + f * step}))
    later = Frame(2 / 30, {}, {"human/right": hand0 + 2 * step})
    assert list(mem.stale_in_hand(later, NOT_HELD)) == [False, True, False]
    at = mem.detections_now(mem.stale_in_hand(later, NOT_HELD), later.t)
    np.testing.assert_allclose(at[CUP, :3], hand0 + 2 * step - [0, 0, 0.2], atol=1e-6)
    np.testing.assert_allclose(at[BALL], mem.last_pose[BALL])  # no hand near it: at its detection
    np.testing.assert_allclose(at[CUP, 3:], mem.last_pose[CUP, 3:])
    assert not mem.stale_in_hand(Frame(2 / 30, {}, {}), NOT_HELD).any()  # the hand is not tracked now
    # seen falling over the reasoning period (5 cm in 0.1 s): the hand near it let it go
    mem.end_tick(mem.perceived(2 / 30), np.array([False, True, True]), np.zeros((3, 3)))
    mem.record(Frame(3 / 30, {"cup": det(mem.last_pose[CUP, :3] - [0, 0, 0.05])}, {"human/right": hand0 + 3 * step}))
    assert mem.tick_velocity()[CUP, 2] < -0.3 and mem.hold_hand[CUP] == "human/right"
    assert not mem.stale_in_hand(Frame(4 / 30, {}, {"human/right": hand0 + 4 * step}), NOT_HELD).any()


def test_a_detection_from_an_earlier_frame_is_carried_on_at_its_velocity_when_seen_moving():
    """An object seen moving, detected in an earlier frame of the update and not in its last one,
    is carried on at its perceived velocity to the update's time (exact on uniform motion: a ball
    rolling at 1 m/s, missed on one frame, is 3.3 cm on); one seen still stays at its detection, and
    so does every object when ``aged`` is not given (the paper's pinning)."""
    mem = memory()
    v = np.array([-1.0, 0.0, 0.0])
    for f in range(0, 5):  # the ball rolls in view; the cup lies still
        mem.record(Frame(f / 30, {"ball": det(np.array([0.3, 0.0, 0.03]) + v * f / 30), "cup": det([0.0, 0.3, 0.05])}))
    mem.record(Frame(5 / 30, {}))  # the last frame of the update shows neither
    assert np.isfinite(mem.moving_since[BALL]) and np.isnan(mem.moving_since[CUP])
    none = np.zeros(3, dtype=bool)
    seen = np.array([False, True, True])
    at = mem.detections_now(none, 5 / 30, seen)
    np.testing.assert_allclose(at[BALL, :3], [0.3 - 5 / 30, 0.0, 0.03], atol=1e-9)
    np.testing.assert_allclose(at[CUP], mem.last_pose[CUP])
    np.testing.assert_allclose(mem.detections_now(none, 5 / 30), mem.last_pose)
    # detected in the update's last frame: at its detection
    mem.record(Frame(6 / 30, {"ball": det(np.array([0.3, 0.0, 0.03]) + v * 6 / 30)}))
    np.testing.assert_allclose(mem.detections_now(none, 6 / 30, seen), mem.last_pose)


def _frames(mem, positions, quats=None, hz=30.0):
    for i, p in enumerate(positions):
        mem.record(Frame(i / hz, {"cup": det(p, None if quats is None else quats[i])}))
    return (len(positions) - 1) / hz


def test_at_rest_needs_a_dwell_of_slow_detections():
    hr = ReasonerConfig(place_dwell=0.3, place_speed=0.15, place_spin=1.0)
    mem = memory(reasoner=hr)
    t = _frames(mem, [[0.3, 0.3, 0.14]] * 13)  # 0.4 s still
    assert list(mem.at_rest(t)) == [False, True, False]
    assert not mem.at_rest(t + 0.31)[CUP]  # not seen for longer than the dwell
    short = memory(reasoner=hr)
    assert not short.at_rest(_frames(short, [[0.3, 0.3, 0.14]] * 5))[CUP]  # 0.13 s: none old enough
    moving = memory(reasoner=hr)  # 0.2 m/s > place_speed
    assert not moving.at_rest(_frames(moving, [[0.3 + 0.2 * i / 30, 0.3, 0.14] for i in range(13)]))[CUP]
    slow = memory(reasoner=hr)  # 0.1 m/s < place_speed
    assert slow.at_rest(_frames(slow, [[0.3 + 0.1 * i / 30, 0.3, 0.14] for i in range(13)]))[CUP]
    turning = memory(reasoner=hr)  # 2 rad/s about z > place_spin
    qs = [[0, 0, math.sin(i / 30), math.cos(i / 30)] for i in range(13)]
    assert not turning.at_rest(_frames(turning, [[0.3, 0.3, 0.14]] * 13, qs))[CUP]


def test_tick_velocity_and_vertical_acceleration():
    mem = memory()
    mem.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.5])}))
    assert np.all(mem.tick_velocity() == 0)  # no previous tick
    mem.end_tick(mem.perceived(0.0), np.array([False, True, False]), mem.tick_velocity())
    mem.record(Frame(0.05, {"cup": det([0.3, 0.3, 0.49])}))
    mem.record(Frame(0.1, {"cup": det([0.3, 0.3, 0.46])}))
    v = mem.tick_velocity()
    assert np.allclose(v[CUP], [0.0, 0.0, -0.4]) and np.all(v[[TABLE, BALL]] == 0)
    assert mem.vertical_acceleration(v, 0.1)[CUP] == pytest.approx(-4.0)
    mem.end_tick(mem.perceived(0.1), np.array([False, True, False]), v)
    mem.record(Frame(0.2, {"cup": det([0.3, 0.3, 0.36])}))
    v2 = mem.tick_velocity()
    assert v2[CUP, 2] == pytest.approx(-1.0)
    assert mem.vertical_acceleration(v2, 0.1)[CUP] == pytest.approx(-6.0)
    mem.end_tick(mem.perceived(0.2), np.zeros(3, bool), v2)  # not detected: its velocity is forgotten
    assert mem.vertical_acceleration(v2, 0.1)[CUP] == pytest.approx(-10.0)


def test_detections_and_hands_outside_the_workspace_are_rejected_and_counted():
    mem = memory()
    lo, hi = mem.workspace
    assert lo[2] == -0.5 and np.all(hi > lo)  # with a floor: half a metre under it
    inside = det([0.1, 0.0, 0.7])
    frame = Frame(1.0, {"ball": det([1e308, 0.0, 0.7]), "cup": det([0.0, 0.0, -50.0])},
                  {"human/right": np.array([0.0, 0.0, 1e300]), "human/left": np.array([0.2, 0.0, 0.9])})
    kept = mem.admit(frame)
    assert kept.objects == {} and list(kept.hands) == ["human/left"] and mem.rejected == 3
    assert mem.admit(Frame(2.0, {"cup": inside})).objects == {"cup": inside} and mem.rejected == 3
    assert "nonsense" in mem.admit(Frame(3.0, {"nonsense": det([1e9, 0, 0])})).objects  # record() reports it



def test_hand_travel_is_the_filtered_hand_displacement_since_the_object_was_last_seen():
    """The hand's position is its filtered one (estimator.model.hands), remembered at each detection of
    the object it holds; hand_travel is the distance from there to the hand now (NaN for objects
    no hand held). Exact positions: a still hand is where it is; one that moved and stopped is,
    after a second, where it stopped."""
    mem = memory()
    a, b = np.array([0.3, 0.3, 0.25]), np.array([0.5, 0.3, 0.3])
    for k in range(3):
        mem.record(Frame(k / 30, {"cup": det([0.3, 0.3, 0.14])}, {"human/right": a}))
    np.testing.assert_allclose(mem.hold_hand_position[CUP], a)
    assert mem.hand_travel()[CUP] == pytest.approx(0.0) and np.isnan(mem.hand_travel()[BALL])
    for k in range(3, 40):
        mem.record(Frame(k / 30, {}, {"human/right": b}))
    assert mem.hand_travel()[CUP] == pytest.approx(np.linalg.norm(b - a), abs=1e-3)


def test_held_offset_is_averaged_over_the_frames_that_show_object_and_hand():
    """A cup held 11 cm under a hand tracked 1 cm off per axis, both seen for 2 s: its offset is
    the average of (detection - raw hand), within 3 standard deviations of the exponential
    average's (sigma sqrt(a / (2 - a)), a the weight of a frame) on every axis, where one frame's
    is sigma; unfiltered, the last frame's difference. A new grasp (a difference beyond the gate)
    starts the average again; hand_target is the filtered hand plus the offset."""
    offset = np.array([0.0, 0.0, -0.11])
    rng = np.random.default_rng(5)
    frames = []
    for k in range(60):
        hand = np.array([0.3 + 0.2 * k / 30, 0.3, 0.25])
        frames.append(Frame(k / 30, {"cup": det(hand + offset)}, {"human/right": hand + rng.normal(0, 0.01, 3)}))
    mem, raw = memory(), memory(hands=HandConfig(filtered=False))
    for f in frames:
        mem.record(f)
        raw.record(f)
    a = 1.0 - math.exp(-(1 / 30) / HandConfig().offset_time)
    assert np.all(np.abs(mem.hold_offset[CUP] - offset) < 3 * 0.01 * math.sqrt(a / (2 - a)))
    last = frames[-1]
    np.testing.assert_allclose(raw.hold_offset[CUP], last.objects["cup"].position - last.hands["human/right"])
    at = mem.hand_target(Frame(2.0, {}, last.hands), CUP)
    np.testing.assert_allclose(at, mem.hand_position("human/right") + mem.hold_offset[CUP])
    regrasp = np.array(last.hands["human/right"]) + [0.0, 0.06, -0.05]
    mem.record(Frame(2.0, {"cup": det(regrasp)}, last.hands))
    np.testing.assert_allclose(mem.hold_offset[CUP], regrasp - last.hands["human/right"])


def test_motion_onset_is_the_last_still_detection_and_ends_when_still_again():
    from estimator.model.perception_memory import MOTION_ONSET

    mem = memory()
    rng = np.random.default_rng(4)
    still = [[0.3, 0.3, 0.14] + rng.normal(0, 0.002, 3) for _ in range(30)]  # 1 s still, 2 mm noise
    t = _frames(mem, still)
    assert np.isnan(mem.moving_since[CUP]) and np.allclose(mem.still_position[CUP], [0.3, 0.3, 0.14], atol=0.003)
    # then it slides at 0.1 m/s: onset at the last detection closer than MOTION_ONSET to where it was
    path = [[0.3 + 0.1 * (i + 1) / 30, 0.3, 0.14] for i in range(15)]
    times = [t + (i + 1) / 30 for i in range(15)]
    for ti, p in zip(times, path):
        mem.record(Frame(ti, {"cup": det(p)}))
    first_far = next(i for i, p in enumerate(path) if p[0] - 0.3 > MOTION_ONSET + 0.003)
    assert times[first_far - 2] - 1e-9 <= mem.moving_since[CUP] <= times[first_far - 1] + 1e-9
    assert mem.moving_since[CUP] > t  # after the still part
    onset = mem.moving_since[CUP]
    # still moving slowly: the onset stays (slow motion is not "still again")
    mem.record(Frame(times[-1] + 1 / 30, {"cup": det([path[-1][0] + 0.003, 0.3, 0.14])}))
    assert mem.moving_since[CUP] == onset
    # at rest for longer than place_dwell: still again, at the new place
    end = times[-1] + 1 / 30
    for i in range(12):
        mem.record(Frame(end + (i + 1) / 30, {"cup": det([path[-1][0] + 0.003, 0.3, 0.14])}))
    assert np.isnan(mem.moving_since[CUP]) and np.isclose(mem.still_position[CUP][0], path[-1][0] + 0.003)
    # after a loss the object starts still wherever it is seen again
    mem.record(Frame(end + 5.0, {"cup": det([0.0, 0.0, 0.14])}))
    assert np.isnan(mem.moving_since[CUP]) and np.allclose(mem.still_position[CUP], [0.0, 0.0, 0.14])


def test_an_object_that_starts_moving_slowly_after_a_pause_is_not_still_again():
    """A cup is lifted slowly (an onset), held, then a hand starts sliding it: over the place_dwell
    before the new detection it moved under MOTION_ONSET (it looks still), but the new detection is
    farther than MOTION_ONSET from the one a place_dwell before it: the onset stays. Held still
    instead, it is still again."""
    from estimator.model.perception_memory import MOTION_ONSET

    for slides in (True, False):
        mem = memory()
        t = _frames(mem, [[0.3, 0.3, 0.14]] * 15)
        lift = [0.145, 0.15, 0.155, 0.16]  # 5 mm a frame: the onset at the third
        dx = [0.0] * 6 + [0.003, 0.010, 0.022] if slides else [0.0] * 9  # frames 5 to 13
        path = [[0.3, 0.3, z] for z in lift] + [[0.3 + x, 0.3, 0.16] for x in dx]
        for k, p in enumerate(path):
            mem.record(Frame(t + (k + 1) / 30, {"cup": det(p)}))
            if k == 3:
                onset = mem.moving_since[CUP]
                assert np.isfinite(onset)
        if slides:
            assert math.dist(path[-1], path[2]) > MOTION_ONSET > math.dist(path[-2], path[2])
            assert mem.moving_since[CUP] == onset
        else:
            assert np.isnan(mem.moving_since[CUP])


def test_shifted_means_moved_along_the_support_not_a_spike():
    mem = memory()
    t = _frames(mem, [[0.3, 0.3, 0.14]] * 15)
    assert not mem.shifted(0.02).any()
    # a detection sunk 3 cm into the table: an onset, but no horizontal shift
    mem.record(Frame(t + 1 / 30, {"cup": det([0.3, 0.3, 0.11])}))
    assert np.isfinite(mem.moving_since[CUP]) and not mem.shifted(0.02)[CUP]
    # dragged 3 cm along the table: shifted
    mem.record(Frame(t + 2 / 30, {"cup": det([0.33, 0.3, 0.14])}))
    assert mem.shifted(0.02)[CUP] and not mem.shifted(0.04)[CUP] and not mem.shifted(0.02)[BALL]


def test_position_at_carries_the_last_detection_on_at_the_perceived_velocity():
    mem = memory()
    mem.record(Frame(0.0, {"cup": det([0.3, 0.3, 0.14])}))
    mem.record(Frame(0.1, {"cup": det([0.4, 0.3, 0.14])}))  # 1 m/s along x
    p = mem.position_at(0.0)
    assert p[CUP] == pytest.approx([0.3, 0.3, 0.14]) and mem.position_at(0.3)[CUP] == pytest.approx([0.6, 0.3, 0.14])
    assert np.all(p[BALL] == mem.last_pose[BALL, :3])  # never seen: where it is


def test_perceived_velocity_starts_at_the_motion_onset():
    """A ball still for 0.33 s, then flicked to 1 m/s: three frames later its perceived velocity is
    the slope since its last still detection (exact), not a line through the still detections
    before the flick too, which lags (half the speed here), and which the paper's mode keeps
    (``from_onset=False``)."""
    for from_onset, speed in ((True, 1.0), (False, 0.5)):
        mem = memory(from_onset=from_onset)
        for f in range(14):
            t = f / 30
            mem.record(Frame(t, {"ball": det([0.3 + max(0.0, t - 10 / 30), 0.0, 0.03])}))
        assert mem.moving_since[BALL] == pytest.approx(10 / 30)
        assert mem.perc_vel[BALL, :3] == pytest.approx([speed, 0.0, 0.0])


def test_perceived_velocity_is_the_least_squares_slope_over_the_window_with_its_standard_error():
    """Exact on a uniform motion (no scatter: no velocity error); on 300 runs of 3 mm detection noise
    at 30 Hz reported by the detector, the slope's errors over ``velocity_std`` have a mean square
    within the chi-square band of 900 values (3 sigma), the scatter about the line estimates the
    noise (mean square within its band), and a frame-to-frame difference is 5 times as noisy; a gap
    longer than t_perceived starts again; the line carries the position on."""
    v = np.array([0.6, -0.1, 0.05])
    times = np.arange(16) / 30.0
    mem = memory()
    for t in times:
        mem.record(Frame(float(t), {"ball": det([0.1, 0.2, 0.3] + v * t)}))
    assert mem.perc_vel[BALL, :3] == pytest.approx(v)
    n = int(round(VELOCITY_WINDOW * 30)) + 1  # detections in the window
    sxx = float(np.sum((np.arange(n) - (n - 1) / 2) ** 2)) / 900.0
    assert mem.perc_vel_sxx[BALL] == pytest.approx(sxx)
    assert mem.velocity_std(0.01)[BALL] == pytest.approx(0.0, abs=1e-9)  # on the line: no error
    assert mem.velocity_std(0.01)[CUP] == 0.0  # never seen: no slope, no noise
    assert mem.position_at(times[-1] + 0.1)[BALL] == pytest.approx([0.1, 0.2, 0.3] + v * (times[-1] + 0.1))
    rng = np.random.default_rng(11)
    z2, s2, diffs = [], [], []
    for _ in range(300):
        mem = memory()
        for t in times:
            mem.record(Frame(float(t), {"ball": det([0.1, 0.2, 0.3] + v * t + rng.normal(0.0, 0.003, 3), std=0.003)}))
        z2.extend(((mem.perc_vel[BALL, :3] - v) / mem.velocity_std(0.01)[BALL]) ** 2)
        s2.append(mem.perc_vel_scatter[BALL] ** 2)
        diffs.extend((np.array(mem._history[BALL][-1][1]) - mem._history[BALL][-2][1]) * 30.0 - v)
    assert mem.velocity_std(0.01)[BALL] == pytest.approx(0.003 / math.sqrt(sxx))
    assert abs(np.mean(z2) - 1.0) < 3 * math.sqrt(2 / len(z2))
    dof = 2 * (n - 2)  # the scatter's degrees of freedom per run
    assert abs(np.mean(s2) / 0.003 ** 2 - 1.0) < 3 * math.sqrt(2 / dof / len(s2))
    assert np.std(diffs) > 5 * mem.velocity_std(0.01)[BALL]
    mem.record(Frame(2.0, {"ball": det([0.5, 0.5, 0.3])}))  # back after a gap: no velocity yet
    assert np.all(mem.perc_vel[BALL] == 0) and mem.velocity_std(0.003)[BALL] == 0
    mem.record(Frame(2.1, {"ball": det([0.52, 0.5, 0.3])}))  # only the detections since the gap count
    assert mem.perc_vel[BALL, :3] == pytest.approx([0.2, 0.0, 0.0])


def test_free_fall_through_the_last_two_detections_is_exact_on_a_parabola():
    """Detections of a ball rolling off an edge at t = 0.1 s (level before, then z = z0 - g t^2 / 2):
    the fall through the last two is the parabola, forwards and backwards while it still descends;
    before it began, the ball is at the fall's top, at rest. Its velocity error is sqrt(2) sigma / dt."""
    g, z0, hz = 9.81, 0.7, 30.0
    mem = memory()
    ts = np.arange(0, 7) / hz
    fall = lambda t: z0 - 0.5 * g * max(t - 0.1, 0.0) ** 2
    for t in ts:
        mem.record(Frame(float(t), {"ball": det([0.5 * t, 0.0, fall(t)], std=0.002)}))
    times = (ts[-1], ts[-1] + 0.05, ts[-1] - 0.04)
    z, v, err = mem.free_fall(times, -g, 0.01)
    for i, t in enumerate(times):
        assert z[i, BALL] == pytest.approx(fall(t), abs=1e-9)
        assert v[i, BALL] == pytest.approx(-g * (t - 0.1), abs=1e-9)
    assert err[BALL] == pytest.approx(math.sqrt(2) * 0.002 * hz)
    z, v, _ = mem.free_fall(0.05, -g, 0.01)
    assert z[0, BALL] == pytest.approx(z0, abs=1e-9) and v[0, BALL] == 0.0
    assert np.isnan(z[0, CUP])  # never detected


def _still_then_lifted(sigma, rng, still_frames=90, lift_frames=15):
    """A memory fed a cup at rest for ``still_frames`` at 30 Hz, then lifted at 0.5 m/s, through a
    tracker with Gaussian noise ``sigma`` (m per axis); its velocities read every third frame, as the
    filter reads them once per update. Returns the memory, the time the lift began and whether the
    cup counted as moving at the last still frame."""
    mem = memory()
    rest = np.array([0.3, 0.3, 0.14])
    still_onsets = False
    for i in range(still_frames + lift_frames):
        t = i / 30.0
        lift = max(0, i - still_frames) / 30.0 * 0.5
        mem.record(Frame(t, {"cup": det(rest + [0, 0, lift] + rng.normal(0.0, sigma, 3))}))
        if i % 3 == 2:
            mem.perc_vel  # the update reads the fitted lines
        if i == still_frames - 1:
            still_onsets = np.isfinite(mem.moving_since[CUP])
    return mem, still_frames / 30.0, still_onsets


def test_the_onset_follows_the_trackers_noise():
    rng = np.random.default_rng(21)
    # a 1 cm tracker: 1.5 cm is 1.5 standard deviations; the onset moves out to about 4 of them
    mem, lift_t, _ = _still_then_lifted(0.01, rng)
    assert mem.noise.std == pytest.approx(0.01, rel=0.2)
    assert mem.onset(CUP) == pytest.approx(ONSET_SIGMAS * mem.noise.std)
    assert lift_t - 0.1 <= mem.moving_since[CUP] <= lift_t + 0.3  # the lift is seen, late by noise
    # a 3 mm tracker keeps the 1.5 cm floor
    mem3, _, _ = _still_then_lifted(0.003, rng)
    assert mem3.onset(CUP) == MOTION_ONSET
    # a detector that states its noise is taken at its word
    mem3.record(Frame(10.0, {"cup": det([0.3, 0.3, 0.14], std=0.02)}))
    assert mem3.onset(CUP) == pytest.approx(ONSET_SIGMAS * 0.02)


def test_a_still_object_under_a_noisy_tracker_is_rarely_set_moving():
    # with the onset at the 1e-3 quantile, 90 noisy frames of a cup at rest set it moving in about
    # 1 - (1 - 1e-3)^90 = 9 % of runs once the noise is measured (the first 0.3 s use the 1.5 cm
    # floor); with the fixed 1.5 cm it happened in almost every run
    rng = np.random.default_rng(3)
    runs = 60
    moved = sum(bool(_still_then_lifted(0.01, rng, still_frames=90, lift_frames=0)[2]) for _ in range(runs))
    p = 1 - (1 - ONSET_FALSE_ALARM) ** 90
    assert moved <= runs * p + 3 * math.sqrt(runs * p * (1 - p)) + 1


def test_a_jump_is_judged_against_the_trackers_noise():
    # two detections of a still cup through a 1 cm tracker differ by N(0, 2 sigma^2) per axis: they
    # are more than d_perc_prev = 3.2 cm apart at P(chi2_3 > 5.12) = 16 % of the updates; measured
    # against the noise (the 1e-3 quantile of that difference) almost never
    rng = np.random.default_rng(8)
    rest = np.array([0.3, 0.3, 0.14])
    mem = memory()
    plain, aware, ticks = 0, 0, 0
    for i in range(330):
        t = i / 30.0
        mem.record(Frame(t, {"cup": det(rest + rng.normal(0.0, 0.01, 3))}))
        if i % 3 == 2:  # an update every third frame, as the filter reads them
            mem.perc_vel
            if t >= 1.0:  # the noise is measured by then
                ticks += 1
                plain += bool(mem.jumped()[CUP])
                aware += bool(mem.jumped(noise_aware=True)[CUP])
            mem.end_tick(mem.perceived(t), np.array([False, True, False]), np.zeros((3, 3)))
    assert mem.noise.std == pytest.approx(0.01, rel=0.2)
    p_plain = 0.16
    assert plain >= ticks * p_plain - 3 * math.sqrt(ticks * p_plain * (1 - p_plain))
    # at most the false-alarm rate of a noise measured 20 % low (the band asserted just above)
    p_aware = float(chi2.sf((0.8 * ONSET_SIGMAS) ** 2, 3))
    assert aware <= ticks * p_aware + 3 * math.sqrt(ticks * p_aware) + 1
    # a real jump of 8 cm is one under the same noise
    mem.record(Frame(11.0, {"cup": det(rest + [0.08, 0.0, 0.0])}))
    assert mem.jumped(noise_aware=True)[CUP]
    # a 3 mm tracker keeps the paper's threshold: a 4 cm move is a jump
    mem3, _, _ = _still_then_lifted(0.003, rng, lift_frames=0)
    mem3.end_tick(mem3.perceived(3.0), np.array([False, True, False]), np.zeros((3, 3)))
    mem3.record(Frame(3.1, {"cup": det(rest + [0.04, 0.0, 0.0])}))
    assert mem3.jumped(noise_aware=True)[CUP] and mem3.jumped()[CUP]
