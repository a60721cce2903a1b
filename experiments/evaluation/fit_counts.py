"""The per-run counts the held-object prior fit adds up (:mod:`experiments.evaluation.fit_priors`
says what each prior is and how it is fitted).

A run is the simulator's: ``obs`` its observation lines (``{"t", "objects": {id: {"position"}},
"hands": {name: [x, y, z]}}``), ``truth`` its truth lines (``{"t", "objects": {id: {"position",
"orientation", "held", "visible"}}, "relations", "hands"}``), or ``result`` with ``scene``,
``observations`` and ``truth``. Times in s, positions ``(3,)`` in m, accelerations in m/s^2. Each
``count_*`` adds one run to its accumulators in place: :class:`Counts` (hits out of samples, for
the probabilities), :class:`Spread` (sums of squared 3-vector deviations, for the standard
deviations) or lists of samples.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.modes import ModePriors
from estimator.applications.tracker import PhysicsAwareTracker, TrackerConfig
from estimator.config import EstimatorConfig, HandConfig, ReasonerConfig, reasoning_due
from estimator.config_sections import RELEASE_DOWN_SPEED
from estimator.model import initial_poses
from estimator.model.hand_memory import HAND_RADIUS
from estimator.model.hands import filtered_track
from estimator.model.perception_memory import PerceptionMemory
from estimator.observations import parse_frame
from physics.visibility import Camera, local_sample_points, visible_fraction
from physics.world import PhysicsSettings, World


@dataclass
class Spread:
    """Sum of squared deviations ``ss`` (m^2) over ``n`` 3-vectors; ``std`` per axis (m)."""

    ss: float = 0.0
    n: int = 0

    @property
    def std(self) -> float:
        return float(np.sqrt(self.ss / (3 * self.n))) if self.n else float("nan")


@dataclass
class Counts:
    """Events counted for one prior: ``hits`` out of ``n``; ``p`` by Laplace's rule."""

    hits: int = 0
    n: int = 0

    @property
    def p(self) -> float:
        return (self.hits + 1) / (self.n + 2)

    def add(self, hit: bool) -> None:
        self.hits += int(hit)
        self.n += 1


def _nearest(times: np.ndarray, t: float) -> int:
    """Index of the entry of ``times`` (s) nearest to ``t``: the truth row of a frame."""
    return int(np.argmin(np.abs(times - t)))


def _hand_track(obs: list[dict]) -> list[np.ndarray | None]:
    """The tracked hand's position ``(3,)`` (m) in each observation line (its first hand), or None."""
    return [None if not o.get("hands") else np.asarray(next(iter(o["hands"].values())), float) for o in obs]


def _filtered(hands: list[np.ndarray | None], t_obs: np.ndarray, config: HandConfig) -> list[np.ndarray | None]:
    """The hand as the estimator's memory reads it at each frame (:func:`~estimator.model.hands.filtered_track`:
    its latest filtered position, None before the first)."""
    raw = np.array([np.full(3, np.nan) if h is None else h for h in hands]).reshape(-1, 3)
    track = filtered_track(t_obs, raw, config)
    out, last = [], None
    for row in track:
        last = row if np.all(np.isfinite(row)) else last
        out.append(last)
    return out


def count_losses(obs: list[dict], truth: list[dict], reasoner: ReasonerConfig, priors: ModePriors,
                 carried: Counts, still: Counts, hidden: Counts | None = None,
                 put_down: Counts | None = None, hands_config: HandConfig | None = None) -> None:
    """Add the losses of held objects in one run (``obs``, ``truth``: the simulator's lines), the hand
    read as the estimator reads it (``hands_config``, default :class:`~estimator.config.HandConfig`);
    ``hidden``: of the carried losses still held at the loss, those let go before the object was
    detected again (or the run ended); ``put_down``: of those let go, the ones that came to rest at
    most ``push_lift`` below the height they were let go at (put down, not dropped)."""
    t_obs = np.array([o["t"] for o in obs])
    t_true = np.array([r["t"] for r in truth])
    hands = _hand_track(obs)
    smooth = _filtered(hands, t_obs, hands_config or HandConfig())
    ids = set().union(*(o["objects"].keys() for o in obs)) if obs else set()
    for oid in sorted(ids):
        seen = [i for i, o in enumerate(obs) if oid in o["objects"]]
        for a, b in zip(seen, seen[1:] + [None]):
            t0 = t_obs[a]
            t_loss = t0 + reasoner.t_perceived
            if (b is not None and t_obs[b] <= t_loss + 1e-9) or t_loss > t_obs[-1]:
                continue
            hand0 = smooth[a]
            pos0 = np.asarray(obs[a]["objects"][oid]["position"], float)
            i0 = _nearest(t_true, t0)
            if hand0 is None or hands[a] is None or np.linalg.norm(hands[a] - pos0) >= HAND_RADIUS:
                continue
            if not truth[i0]["objects"][oid].get("held"):
                continue
            f_loss = int(np.searchsorted(t_obs, t_loss - 1e-9))
            hand1 = smooth[min(f_loss, len(obs) - 1)]
            if hand1 is None:
                continue
            i1 = _nearest(t_true, t_loss)
            released = not truth[i1]["objects"][oid].get("held")
            moved = float(np.linalg.norm(hand1 - hand0)) > priors.carry_distance
            (carried if moved else still).add(released)
            if moved and not released and hidden is not None:
                i2 = len(truth) if b is None else int(np.searchsorted(t_true, t_obs[b]))
                let = next((i for i in range(i1, i2) if not truth[i]["objects"][oid].get("held")), None)
                hidden.add(let is not None)
                if let is not None and put_down is not None:  # it came to rest where it was let go
                    drop = truth[let - 1]["objects"][oid]["position"][2] - truth[i2 - 1]["objects"][oid]["position"][2]
                    put_down.add(bool(drop <= reasoner.push_lift))


def count_offsets(result, config: EstimatorConfig, spread: Spread, hand_error: Spread | None = None) -> None:
    """Add to ``spread`` the deviations of held, undetected objects from where the estimator's
    perception memory (``config.reasoner``, ``config.hands``; replayed on the stream of ``result``,
    the simulator's) puts them by their hand (:meth:`~estimator.model.perception_memory.PerceptionMemory.hand_target`),
    one per frame while the truth holds them; to ``hand_error``, the tracked minus the true hand of
    every frame with a tracked hand the truth also has."""
    scene = result.scene
    memory = PerceptionMemory(scene, initial_poses(scene)[0], config.reasoner, follow_hands=True,
                              hands=config.hands)
    t_true = np.array([r["t"] for r in result.truth])
    ids = scene.object_ids
    for line in result.observations:
        frame = memory.admit(parse_frame(line, known_ids=ids))
        detected = memory.record(frame)
        row = result.truth[_nearest(t_true, frame.t)]
        if hand_error is not None:
            for name, p in frame.hands.items():
                if name in (row.get("hands") or {}):
                    d = np.asarray(p, float) - np.asarray(row["hands"][name], float)
                    hand_error.ss += float(d @ d)
                    hand_error.n += 1
        for m, oid in enumerate(ids):
            o = row["objects"].get(oid, {})
            if detected[m] or not o.get("held"):
                continue
            at = memory.hand_target(frame, m)
            if at is not None:
                d = np.asarray(o["position"], float) - at
                spread.ss += float(d @ d)
                spread.n += 1


def count_set_downs(obs: list[dict], truth: list[dict], priors: ModePriors, touched: Counts,
                    hands_config: HandConfig | None = None) -> None:
    """Add the set-downs out of view of one run (``obs``, ``truth``: the simulator's lines): an object
    held in truth and not detected rests on something (a truth relation with it as subject) while
    held, and then the tracked hand (filtered as the estimator does, ``hands_config``) rises more
    than ``carry_distance`` above its height at that moment, before the object is detected again: a
    hit when the object is no longer held in truth then. One sample per such stretch out of view."""
    t_true = np.array([r["t"] for r in truth])
    hands = _filtered(_hand_track(obs), np.array([o["t"] for o in obs]), hands_config or HandConfig())
    ids = sorted({oid for r in truth for oid, o in r["objects"].items() if o.get("held")})
    for oid in ids:
        touch_z = None  # the filtered hand's height when the held object rested, out of view
        for f, o in enumerate(obs):
            if oid in o["objects"]:
                touch_z = None
                continue
            row = truth[_nearest(t_true, o["t"])]
            hand = hands[f]
            if hand is None or touch_z is False:
                continue
            if touch_z is None:
                resting = any(r["subject"] == oid for r in row["relations"])
                if row["objects"][oid].get("held") and resting:
                    touch_z = float(hand[2])
            elif hand[2] - touch_z > priors.carry_distance:
                touched.add(not row["objects"][oid].get("held"))
                touch_z = False  # counted: wait for the object to be detected again


def count_out_of_reach(obs: list[dict], truth: list[dict], out_of_reach: Counts) -> None:
    """Add the frames of one run (``obs``, ``truth``: the simulator's lines) with a tracked hand in
    which an object held in truth is detected: a hit when no tracked hand is within
    :data:`~estimator.model.hand_memory.HAND_RADIUS` of the detection."""
    t_true = np.array([r["t"] for r in truth])
    for o in obs:
        if not o.get("hands") or not o["objects"]:
            continue
        row = truth[_nearest(t_true, o["t"])]["objects"]
        hands = np.array([np.asarray(h, float) for h in o["hands"].values()])
        for oid, det in o["objects"].items():
            if row.get(oid, {}).get("held"):
                d = np.linalg.norm(hands - np.asarray(det["position"], float), axis=1).min()
                out_of_reach.add(bool(d > HAND_RADIUS))


def count_hand_occlusion(result, threshold: float, occluded: Counts) -> None:
    """Add the frames of one run where a truly held object would be in view of the scene alone (the
    estimator's worlds: no hand, no person): a hit when the truth (with the hand and the person)
    does not show it. Every held frame counts, seen or not: conditioning on the object having gone
    unseen since it was carried would select the hits."""
    scene = result.scene
    if scene.camera is None:
        return
    camera = Camera(scene.camera)
    with World(scene, PhysicsSettings()) as world:
        points: dict[int, np.ndarray] = {}
        for row in result.truth:
            for oid, o in row["objects"].items():
                if not o.get("held"):
                    continue
                m = scene.index(oid)
                if m not in points:
                    points[m] = local_sample_points(world, m, 2)
                pose = np.concatenate([o["position"], o["orientation"]])[None]
                world.set_poses(pose, [m])
                if visible_fraction(world, camera, [m], points, pose)[0] >= threshold:
                    occluded.add(not o["visible"])


def count_accelerations(truth: list[dict], samples: list[float]) -> None:
    """Add to ``samples`` the accelerations (m/s^2, one per axis, signed) of the objects held in
    truth at three consecutive rows of ``truth`` (the simulator's), by second differences of their
    true positions."""
    t = np.array([r["t"] for r in truth])
    if len(t) < 3:
        return
    for oid in truth[0]["objects"]:
        p = np.array([r["objects"][oid]["position"] for r in truth], dtype=float)
        held = np.array([bool(r["objects"][oid].get("held")) for r in truth])
        v = np.diff(p, axis=0) / np.diff(t)[:, None]
        a = np.diff(v, axis=0) / (0.5 * (t[2:] - t[:-2]))[:, None]
        samples += a[held[:-2] & held[1:-1] & held[2:]].ravel().tolist()


def count_descents(result, reasoner: ReasonerConfig, held: list[float], let_go: list[float],
                   window: float = 0.5, filtered: bool = False) -> None:
    """Add the perceived downward accelerations (m/s^2, positive down; as the Release rule measures
    them) of objects perceived moving down at ``RELEASE_DOWN_SPEED`` or more in one run (``result``:
    the simulator's): to ``held``, each reasoning step at which the truth held the object at that step
    and the one before; to ``let_go``, for each time the truth let an object go, the largest over
    the steps of the following ``window`` seconds (s) while it stays let go (the rule may fire at
    any of them; none if it was never seen falling then). ``filtered``: the stream as the Kalman
    tracker filters it (:class:`~estimator.applications.tracker.PhysicsAwareTracker`, no feedback; what
    ``scene-estimator track`` writes and the estimator also takes), whose accelerations are damped."""
    scene, M = result.scene, len(result.scene.objects)
    tracker = PhysicsAwareTracker(TrackerConfig(feed_estimator=True), tuple(o.id for o in scene.objects
                                                                            if not o.static)) if filtered else None
    memory = PerceptionMemory(scene, initial_poses(scene)[0], reasoner, follow_hands=True)
    t_true = np.array([r["t"] for r in result.truth])
    ids = scene.object_ids

    def held_at(t: float) -> np.ndarray:
        row = result.truth[_nearest(t_true, t)]["objects"]
        return np.array([bool(row.get(oid, {}).get("held")) for oid in ids])

    t_tick, was_held, since = None, np.zeros(M, dtype=bool), np.zeros(M, dtype=bool)
    let_at = np.full(M, np.nan)  # when the truth last let each object go (within the window)
    best = np.full(M, np.nan)  # the largest acceleration since
    for line in result.observations:
        frame = parse_frame(line, known_ids=ids)
        if tracker is not None:
            tracker.update(frame)
            frame = tracker.to_frame(hands=frame.hands, detected_only=True)
        frame = memory.admit(frame)
        since |= memory.record(frame)
        if not reasoning_due(t_tick, frame.t, reasoner.horizon):
            continue
        vel = memory.tick_velocity()
        now = held_at(frame.t)
        if t_tick is not None:
            down = -memory.vertical_acceleration(vel, min(frame.t - t_tick, reasoner.max_gap))
            falling = since & (vel[:, 2] < -RELEASE_DOWN_SPEED)
            held += down[was_held & now & falling].tolist()
            let_at[was_held & ~now] = frame.t
            open_ = np.isfinite(let_at) & ~now & (frame.t - let_at <= window)
            best[open_ & falling] = np.fmax(best[open_ & falling], down[open_ & falling])
            closed = np.isfinite(let_at) & ~open_
            let_go += best[closed & np.isfinite(best)].tolist()
            let_at[closed], best[closed] = np.nan, np.nan
        memory.end_tick(memory.perceived(frame.t), since, vel)
        t_tick, was_held, since = frame.t, now, np.zeros(M, dtype=bool)
    let_go += best[np.isfinite(let_at) & np.isfinite(best)].tolist()
