"""Ground-truth simulation of a scenario: a scripted human hand acting on a scene, a synthetic camera,
a faulty pose tracker, and the files an experiment runs on.

The ground truth runs in its own pybullet world (a :class:`physics.world.World` built from the
scenario's scene, plus a hand and an optional torso), never in the estimator's. One run:

1. :func:`sample_variant` draws the seeded variant of a :class:`~experiments.scenarios.Scenario`
   (geometry, masses, frictions, timing) with ``numpy.random.default_rng(seed)``;
2. :class:`GroundTruth` builds the world, lets it settle for ``scenario.settle`` seconds (the settled
   poses are the true initial poses), then steps it at 240 Hz while the hand follows its script;
3. at every camera frame (``perception.rate_hz``) it records the truth (poses, visibility, held
   objects, relations, events) and, through :class:`~experiments.simulation.camera.SyntheticCamera` and
   :class:`~experiments.simulation.perception.PerceptionModel`, what the tracker reports;
4. :func:`write_outputs` writes ``scene.yaml``, ``observations.jsonl``, ``truth.jsonl`` and
   ``meta.json``; the same scenario and seed give byte-identical files.

The hand is a dynamic sphere pulled along its script by a fixed constraint to the world
(``changeConstraint`` moves the constraint's target every step, with a bounded force), so it pushes
objects physically when it collides (``collide: true``) and passes through them otherwise. A grasp is
a fixed constraint between the hand and the object at their relative pose of the moment; a release
removes it. The hand never collides with an object it holds.

Truth events (the estimator uses the same semantics):

* ``Pick``: the hand grasps an object (at the grasp time);
* ``Place``: the hand lets go of an object that rests on a support: it touches a body other than the
  hand, or the bounding-box relations (:mod:`estimator.relations`, 1.5 cm tolerance) put it on top of
  or inside another object or on the floor;
* ``Release``: the hand lets go of an object in the air (it falls, is dropped, is thrown);
* ``Push``: the hand, pushing (``collide``), moves an object it does not grasp along its support,
  never lifting it (:mod:`experiments.simulation.pushes`; at the time it started moving).

Objects moved only by other objects (a cup shoved off the table by a pushed box) and contents
carried inside a container the hand holds or pushes (the ball of a box being poured) get no event.
Events are listed in time order, each in the first truth frame at or after its time.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from scipy.spatial.transform import Rotation
import pybullet as pb
import yaml

from estimator.relations import relation_list, relation_masks
from physics.errors import InputError
from physics.scene import CameraSpec, Scene, scene_to_dict
from physics.transforms import pose_compose, pose_inverse, quat_from_axis_angle, quat_multiply, quat_normalize
from physics.bodies import DEFAULT_PRIMITIVE_MASS
from physics.world import PhysicsSettings, World

from experiments.simulation.camera import SyntheticCamera
from experiments.simulation.perception import PerceptionModel
from experiments.simulation.pushes import PUSH_GAP, PushTracker
from experiments.scenarios import HandTarget, Scenario, Waypoint, load_scenario

FORMAT_VERSION = 1
HAND_ID = "human/right"
DECIMALS = 6
GRASP_REACH = 0.04
"""A grasp needs the object's bounding box within hand radius + this distance (m) of the hand centre."""
CONTACT_DISTANCE = 0.003
"""At a release, an object with a contact closer than this (m) rests on a support (a Place)."""


# --------------------------------------------------------------------------------------------------
# seeded variants


@dataclass(frozen=True)
class Variant:
    """One seeded instance of a scenario: the true scene (before settling), the retimed hand script,
    and the sampled values (``sampled``, plain JSON) for meta.json."""

    scenario: Scenario
    seed: int
    scene: Scene
    script: tuple[Waypoint, ...]
    sampled: dict


def _resize(spec, factor: float):
    """``spec`` scaled by ``factor`` about its centre, moved so that its bottom stays put (primitives
    are assumed upright; URDFs scale about their frame)."""
    kw: dict[str, Any] = {}
    half_before = half_after = 0.0
    factor = round(factor, DECIMALS)
    if spec.shape in ("box", "container"):
        kw["size"] = tuple(_r(v * factor) for v in spec.size)
        half_before, half_after = spec.size[2] / 2, kw["size"][2] / 2
    elif spec.shape == "sphere":
        kw["radius"] = _r(spec.radius * factor)
        half_before, half_after = spec.radius, kw["radius"]
    elif spec.shape == "cylinder":
        kw["radius"], kw["height"] = _r(spec.radius * factor), _r(spec.height * factor)
        half_before, half_after = spec.height / 2, kw["height"] / 2
    else:
        kw["scale"] = _r(spec.scale * factor)
    if spec.position is not None:
        p = list(spec.position)
        p[2] += half_after - half_before
        kw["position"] = tuple(p)
    return replace(spec, **kw)


def sample_variant(scenario: Scenario, seed: int) -> Variant:
    """Draw the variant of ``scenario`` for ``seed`` (``numpy.random.default_rng(seed)``).

    Draws happen in a fixed order: objects in scene order, each in the order position (x, y, z), yaw,
    size, mass, friction, rolling_friction, spinning_friction, restitution; then one duration factor
    per waypoint and the script delay.
    """
    rng = np.random.default_rng(seed)
    rand = {r.id: r for r in scenario.randomize.objects}
    objects = list(scenario.scene.objects)
    sampled_objects: dict[str, Any] = {}
    for i, spec in enumerate(objects):
        r = rand.get(spec.id)
        if r is None:
            continue
        rec: dict[str, Any] = {}
        if r.position is not None:
            d = [float(rng.uniform(lo, hi)) for lo, hi in r.position]
            if spec.position is not None:
                spec = replace(spec, position=tuple(float(a + b) for a, b in zip(spec.position, d)))
            rec["position_offset"] = d
        if r.yaw_deg is not None:
            yaw = float(rng.uniform(*r.yaw_deg))
            q = quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(yaw)),
                              np.asarray(spec.orientation))
            spec = replace(spec, orientation=tuple(float(v) for v in quat_normalize(q)))
            rec["yaw_deg"] = yaw
        if r.size is not None:
            factor = float(rng.uniform(*r.size))
            spec = _resize(spec, factor)
            rec["size_factor"] = factor
        if r.mass is not None:
            factor = float(rng.uniform(*r.mass))
            base = spec.mass if spec.mass is not None else DEFAULT_PRIMITIVE_MASS
            spec = replace(spec, mass=base * factor)
            rec["mass"] = spec.mass
        for key in ("friction", "rolling_friction", "spinning_friction", "restitution"):
            lo_hi = getattr(r, key)
            if lo_hi is not None:
                value = float(rng.uniform(*lo_hi))
                spec = replace(spec, **{key: value})
                rec[key] = value
        objects[i] = spec
        sampled_objects[spec.id] = rec
    script: tuple[Waypoint, ...] = ()
    timing: dict[str, Any] = {}
    if scenario.hand is not None:
        wps = scenario.hand.script
        lo, hi = scenario.randomize.time_scale
        scales = [float(rng.uniform(lo, hi)) if hi > lo else lo for _ in wps]
        dlo, dhi = scenario.randomize.delay
        delay = float(rng.uniform(dlo, dhi)) if dhi > dlo else dlo
        times, t_prev, t_new = [], 0.0, delay
        for wp, s in zip(wps, scales):
            t_new += (wp.t - t_prev) * s
            t_prev = wp.t
            times.append(t_new)
        limit = scenario.duration - 0.1
        if times and times[-1] > limit:  # keep the whole script inside the run
            k = max(limit - delay, 0.0) / max(times[-1] - delay, 1e-9)
            times = [delay + (t - delay) * k for t in times]
        script = tuple(replace(wp, t=float(t)) for wp, t in zip(wps, times))
        timing = {"delay": delay, "segment_scale": scales}
    sampled = {"objects": sampled_objects, "timing": timing}
    return Variant(scenario=scenario, seed=int(seed), scene=scenario.scene.with_objects(objects),
                   script=script, sampled=sampled)


# --------------------------------------------------------------------------------------------------
# the ground-truth world


def _quat_from_rpy(rpy_deg) -> np.ndarray:
    """Quaternion (x, y, z, w) of roll, pitch, yaw in degrees (fixed axes x, y, z)."""
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_quat()


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    d = float(np.dot(a, b))
    if d < 0.0:
        b, d = -b, -d
    if d > 0.9995:
        q = a + s * (b - a)
        return q / np.linalg.norm(q)
    theta = math.acos(min(1.0, d))
    return (math.sin((1 - s) * theta) * a + math.sin(s * theta) * b) / math.sin(theta)


def _smooth(s: float) -> float:
    """Smoothstep: position profile with zero velocity at both ends of a motion."""
    s = min(1.0, max(0.0, s))
    return s * s * (3.0 - 2.0 * s)


@dataclass
class _Segment:
    t0: float
    t1: float
    p0: np.ndarray
    p1: np.ndarray
    q0: np.ndarray
    q1: np.ndarray

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        s = 1.0 if self.t1 <= self.t0 else _smooth((t - self.t0) / (self.t1 - self.t0))
        return self.p0 + (self.p1 - self.p0) * s, _slerp(self.q0, self.q1, s)


class GroundTruth:
    """The true world of a variant: scene objects, hand, torso and camera, stepped at 240 Hz.

    Use as a context manager (it owns a pybullet client). :meth:`run` simulates the whole scenario.
    """

    def __init__(self, variant: Variant, settings: PhysicsSettings | None = None):
        self.variant = variant
        self.scenario = variant.scenario
        self.world = World(variant.scene, settings or PhysicsSettings())
        self.dt = self.world.settings.time_step
        self.hand_uid = -1
        self.torso_uid = -1
        self.held: dict[int, int] = {}  # object index -> constraint id
        self.collide = False
        self.events: list[tuple[int, dict]] = []  # (step, event)
        self.pushes = PushTracker(int(round(PUSH_GAP / self.dt)))
        self.warnings: list[str] = []
        try:
            self._build_hand()
            self._build_torso()
            cam = variant.scene.camera
            cfg = self.scenario.perception
            self.camera = (SyntheticCamera(self.world, cam, points_per_object=cfg.points_per_object,
                                           threshold=cfg.visibility_threshold) if cam is not None else None)
        except BaseException:
            self.world.close()
            raise

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> "GroundTruth":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- bodies -------------------------------------------------------------------------------------
    def _all_bodies(self) -> list[tuple[int, int]]:
        """(uid, link) of every scene body and link, and the floor."""
        c = self.world.client
        out = [(self.world.floor_uid, -1)] if self.world.floor_uid >= 0 else []
        for uid in self.world.uids:
            out.extend((uid, link) for link in range(-1, pb.getNumJoints(uid, physicsClientId=c)))
        return out

    def _build_hand(self) -> None:
        hand = self.scenario.hand
        if hand is None:
            return
        c = self.world.client
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=hand.radius, physicsClientId=c)
        q = _quat_from_rpy(hand.rpy_deg)
        start = np.asarray(hand.start, dtype=float)
        self.hand_uid = pb.createMultiBody(hand.mass, shape, -1, start.tolist(), q.tolist(), physicsClientId=c)
        pb.changeDynamics(self.hand_uid, -1, activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING,
                          linearDamping=0.0, angularDamping=0.0, physicsClientId=c)
        self.hand_constraint = pb.createConstraint(self.hand_uid, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0],
                                                   [0, 0, 0], start.tolist(), childFrameOrientation=q.tolist(),
                                                   physicsClientId=c)
        pb.changeConstraint(self.hand_constraint, maxForce=hand.max_force, physicsClientId=c)
        self._set_collide(hand.collide)
        self.segment = _Segment(0.0, 0.0, start, start, q, q)
        self.next_waypoint = 0
        if hand.holding is not None:
            self._grasp(self.world.index(hand.holding), step=0, event=False)

    def _build_torso(self) -> None:
        torso = self.scenario.torso
        if torso is None:
            return
        c = self.world.client
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[v / 2 for v in torso.size],
                                        physicsClientId=c)
        self.torso_uid = pb.createMultiBody(0, shape, -1, list(torso.position), physicsClientId=c)
        bodies = self._all_bodies() + ([(self.hand_uid, -1)] if self.hand_uid >= 0 else [])
        for uid, link in bodies:
            pb.setCollisionFilterPair(self.torso_uid, uid, -1, link, 0, physicsClientId=c)

    def _set_collide(self, on: bool) -> None:
        c = self.world.client
        held_uids = {self.world.uids[i] for i in self.held}
        for uid, link in self._all_bodies():
            enable = int(on and uid not in held_uids)
            pb.setCollisionFilterPair(self.hand_uid, uid, -1, link, enable, physicsClientId=c)
        self.collide = on

    # -- hand actions -------------------------------------------------------------------------------
    def hand_position(self) -> np.ndarray | None:
        if self.hand_uid < 0:
            return None
        p, _q = pb.getBasePositionAndOrientation(self.hand_uid, physicsClientId=self.world.client)
        return np.array(p, dtype=float)

    def _grasp(self, index: int, step: int, event: bool = True, where: str = "hand.holding") -> None:
        c = self.world.client
        uid = self.world.uids[index]
        hp, hq = pb.getBasePositionAndOrientation(self.hand_uid, physicsClientId=c)
        box = self.world.aabbs([index])[0]
        gap = float(np.linalg.norm(np.asarray(hp) - np.clip(hp, box[0], box[1])))
        if gap > self.scenario.hand.radius + GRASP_REACH:
            raise InputError(f"the hand is {gap:.3f} m away from {self.world.object_ids[index]!r} "
                             f"when grasping it (at t = {step * self.dt:.3f} s)",
                             path=self.scenario.source, field=where)
        op, oq = pb.getBasePositionAndOrientation(uid, physicsClientId=c)  # centre-of-mass frames
        rel = pose_compose(pose_inverse(np.array([*hp, *hq])), np.array([*op, *oq]))
        rel_p, rel_q = rel[:3].tolist(), rel[3:].tolist()
        cid = pb.createConstraint(self.hand_uid, -1, uid, -1, pb.JOINT_FIXED, [0, 0, 0], rel_p, [0, 0, 0],
                                  parentFrameOrientation=rel_q, childFrameOrientation=[0, 0, 0, 1],
                                  physicsClientId=c)
        pb.changeConstraint(cid, maxForce=self.scenario.hand.max_force, physicsClientId=c)
        pb.setCollisionFilterPair(self.hand_uid, uid, -1, -1, 0, physicsClientId=c)
        self.held[index] = cid
        self.pushes.cancel(index)  # grasped: a Pick, not a push
        if event:
            self._event(step, "Pick", index)

    def _release(self, index: int, step: int) -> None:
        c = self.world.client
        uid = self.world.uids[index]
        pb.removeConstraint(self.held.pop(index), physicsClientId=c)
        pb.setCollisionFilterPair(self.hand_uid, uid, -1, -1, int(self.collide), physicsClientId=c)
        self._event(step, "Place" if self.supported(index) else "Release", index)

    def supported(self, index: int) -> bool:
        """Whether object ``index`` rests on a support: it touches a body other than the hand, or the
        bounding-box relations put it on top of something (the floor included) or inside a
        container (so a cup let go a few millimetres above the table is placed, not dropped)."""
        c = self.world.client
        uid = self.world.uids[index]
        contacts = [p for p in pb.getContactPoints(bodyA=uid, physicsClientId=c)
                    if p[2] != self.hand_uid and p[8] < CONTACT_DISTANCE]
        if contacts:
            return True
        on_top, is_in = relation_masks(self.world.aabbs(), static=self.world.static,
                                       floor=self.world.scene.floor, hollow=self.world.scene.hollow)
        return bool(on_top[index].any() or is_in[index].any())

    def _track_pushes(self, step: int) -> None:
        """Follow the objects the pushing hand touches (:class:`~experiments.simulation.pushes.PushTracker`)
        and record a ``Push`` for each episode that ends as one. Held objects, static ones and
        contents of a container the hand holds or touches start no episode."""
        if self.hand_uid < 0 or (not self.collide and not self.pushes.active):
            return
        touched: set[int] = set()
        if self.collide:
            world = self.world
            for p in pb.getContactPoints(bodyA=self.hand_uid, physicsClientId=world.client):
                i = world.index_of_uid(p[2])
                if i >= 0 and not world.static[i] and i not in self.held:
                    touched.add(i)
            new = [i for i in touched if i not in self.pushes.active]
            if new:
                touched -= self._carried(new, touched)
        idx = sorted(touched | set(self.pushes.active))
        if not idx:
            return
        poses = self.world.get_poses(idx)
        ended = self.pushes.step(step, touched, {i: poses[j, :3] for j, i in enumerate(idx)})
        for i, start in ended:
            self._event(start, "Push", i)

    def _carried(self, indices: list[int], touched: set[int]) -> set[int]:
        """The objects of ``indices`` inside a container (isIn) that the hand holds, touches or is
        pushing: carried with it, not pushed themselves."""
        moving = set(self.held) | touched | set(self.pushes.active)
        _on_top, is_in = relation_masks(self.world.aabbs(), static=self.world.static,
                                        floor=self.world.scene.floor, hollow=self.world.scene.hollow)
        return {i for i in indices if any(is_in[i, j] for j in moving if j != i)}

    def _event(self, step: int, action: str, index: int) -> None:
        self.events.append((step, {"t": _r(step * self.dt), "action": action,
                                   "subject": self.world.object_ids[index], "p": 1.0}))

    def _resolve(self, target: HandTarget | None, previous: np.ndarray) -> np.ndarray:
        if target is None:
            return previous
        if target.position is not None:
            return np.asarray(target.position, dtype=float)
        if target.by is not None:
            return previous + np.asarray(target.by, dtype=float)
        pos = self.world.get_poses([self.world.index(target.object)])[0, :3]
        return pos + np.asarray(target.offset, dtype=float)

    def _start_segment(self, t0: float) -> None:
        script = self.variant.script
        k = self.next_waypoint
        p0, q0 = self.segment.p1, self.segment.q1
        if k >= len(script):
            self.segment = _Segment(t0, t0, p0, p0, q0, q0)
            return
        wp = script[k]
        p1 = self._resolve(wp.to, p0)
        q1 = _quat_from_rpy(wp.rpy_deg) if wp.rpy_deg is not None else q0
        self.segment = _Segment(t0, wp.t, p0, p1, q0, q1)

    def _advance_script(self, t: float, step: int) -> None:
        script = self.variant.script
        while self.next_waypoint < len(script) and script[self.next_waypoint].t <= t + 1e-9:
            k = self.next_waypoint
            wp = script[k]
            if wp.release is not None:
                self._release(self.world.index(wp.release), step)
            if wp.grasp is not None:
                self._grasp(self.world.index(wp.grasp), step, where=f"hand.script[{k}].grasp")
            if wp.collide is not None:
                self._set_collide(wp.collide)
            self.next_waypoint += 1
            self._start_segment(wp.t)

    def _drive_hand(self, t: float) -> None:
        p, q = self.segment.at(t)
        pb.changeConstraint(self.hand_constraint, jointChildPivot=p.tolist(),
                            jointChildFrameOrientation=q.tolist(), maxForce=self.scenario.hand.max_force,
                            physicsClientId=self.world.client)

    # -- the run ------------------------------------------------------------------------------------
    def settle(self) -> None:
        """Simulate ``scenario.settle`` seconds with the hand at its start; the state reached is t = 0."""
        n = int(round(self.scenario.settle / self.dt))
        for _ in range(n):
            if self.hand_uid >= 0:
                self._drive_hand(0.0)
            self.world.step(1)
        if self.hand_uid >= 0:
            self._start_segment(0.0)
            self._advance_script(0.0, 0)

    def look(self, camera: CameraSpec) -> np.ndarray:
        """Visible fractions ``(M,)`` of every object to ``camera`` in the world's present state
        (hand and torso occlude; the scenario's sample points and nothing else changed)."""
        cfg = self.scenario.perception
        base = self.camera or SyntheticCamera(self.world, camera, points_per_object=cfg.points_per_object,
                                              threshold=cfg.visibility_threshold)
        return base.moved_to(camera).visible_fractions()

    def _frame_events(self, truth: list[dict], steps: list[int]) -> list[dict]:
        """All events in time order (a Push is known only when its episode ends, after its time),
        each also listed in ``truth`` (the frames, at simulation ``steps``) in the first frame at or
        after its time. Returns the list."""
        ordered = sorted(self.events, key=lambda se: se[0])  # stable: same-step events keep their order
        j = 0
        for s, e in ordered:
            while j < len(steps) and steps[j] < s:
                j += 1
            if j < len(steps):
                truth[j]["events"].append(e)
        return [e for _s, e in ordered]

    def visible_fractions(self, poses: np.ndarray) -> np.ndarray:
        if self.camera is None:
            return np.ones(self.world.num_objects)
        return self.camera.visible_fractions(poses)

    def run(self, duration: float, perception_rng: np.random.Generator) -> "SimulationResult":
        """Settle, then simulate ``duration`` seconds; returns the recorded streams."""
        cfg = self.scenario.perception
        world = self.world
        self.settle()
        initial_poses = world.get_poses()
        n_steps = int(round(duration / self.dt))
        n_frames = int(math.floor(duration * cfg.rate_hz + 1e-9))
        frame_times = [j / cfg.rate_hz for j in range(1, n_frames + 1)]
        frame_steps = [int(round(t / self.dt)) for t in frame_times]
        frame_of_step = {s: j for j, s in enumerate(frame_steps)}
        lag = int(round(cfg.latency_s / self.dt))
        captures = {s - lag for s in frame_steps if s - lag >= 0}
        model = PerceptionModel(cfg, world.object_ids, world.static, perception_rng)
        snapshots: dict[int, tuple] = {}
        truth: list[dict] = []
        observations: list[dict] = []
        previous = None
        truth_steps: list[int] = []

        def snapshot() -> tuple:
            poses = world.get_poses()
            frac = self.visible_fractions(poses)
            return poses, frac, self.hand_position()

        if 0 in captures:
            snapshots[0] = snapshot()
        for step in range(1, n_steps + 1):
            t = step * self.dt
            if self.hand_uid >= 0:
                self._drive_hand(t)
            world.step(1)
            if self.hand_uid >= 0:
                self._advance_script(t, step)
                self._track_pushes(step)
            is_frame = step in frame_of_step
            if not is_frame and step not in captures:
                continue
            snap = snapshot()
            if step in captures:
                snapshots[step] = snap
            if not is_frame:
                continue
            t_frame = _r(frame_times[frame_of_step[step]])
            poses, frac, hand = snap
            aabbs = world.aabbs()
            previous = relation_masks(aabbs, static=world.static, floor=world.scene.floor, previous=previous,
                                      hollow=world.scene.hollow)
            held = set(self.held)
            objects = {}
            for i, oid in enumerate(world.object_ids):
                objects[oid] = {"position": _rl(poses[i, :3]), "orientation": _rl(poses[i, 3:]),
                                "visible": bool(frac[i] >= cfg.visibility_threshold),
                                "visible_fraction": _r(frac[i]), "held": i in held}
            line: dict[str, Any] = {"t": t_frame, "objects": objects,
                                    "relations": relation_list(previous[0], previous[1], world.object_ids),
                                    "events": []}
            if hand is not None:
                line["hands"] = {HAND_ID: _rl(hand)}
            truth.append(line)
            truth_steps.append(step)
            cap = snapshots.pop(step - lag, None)
            if cap is None:
                continue
            c_poses, c_frac, c_hand = cap
            obs = model.observe(c_poses, c_frac >= cfg.visibility_threshold, c_hand)
            seen = {oid: {"position": _rl(obs.poses[i, :3]), "orientation": _rl(obs.poses[i, 3:])}
                    for i, oid in enumerate(world.object_ids) if obs.reported[i]}
            frame: dict[str, Any] = {"t": t_frame, "objects": seen}
            if obs.hand is not None:
                frame["hands"] = {HAND_ID: _rl(obs.hand)}
            observations.append(frame)
        for i, start in self.pushes.finish():
            self._event(start, "Push", i)
        events = self._frame_events(truth, truth_steps)
        return SimulationResult(initial_poses=initial_poses, truth=truth, observations=observations,
                                events=events, warnings=list(self.warnings),
                                height_offsets=model.height_offsets.copy())


# --------------------------------------------------------------------------------------------------
# results and files


def _r(x: float) -> float:
    """Round to :data:`DECIMALS` decimals, without negative zeros."""
    return round(float(x), DECIMALS) + 0.0


def _rl(values) -> list[float]:
    return [_r(v) for v in values]


@dataclass
class SimulationResult:
    """Streams of one run: ``truth`` and ``observations`` (one dict per line of the JSONL files),
    all ``events``, the settled ``initial_poses`` (M, 7), and the per-object ``height_offsets`` (m)
    the tracker applies. :func:`simulate` fills ``scene`` (for scene.yaml) and ``meta``."""

    initial_poses: np.ndarray
    truth: list[dict]
    observations: list[dict]
    events: list[dict]
    warnings: list[str]
    height_offsets: np.ndarray
    scene: Scene | None = None
    meta: dict | None = None


def estimator_scene(variant: Variant, initial_poses: np.ndarray) -> Scene:
    """The scene handed to the estimator: the true geometry at the true settled initial poses, with
    the scenario's *nominal* masses, frictions and restitution (the estimator does not know the
    sampled ones; they are in meta.json)."""
    nominal = {o.id: o for o in variant.scenario.scene.objects}
    objects = []
    for i, spec in enumerate(variant.scene.objects):
        nom = nominal[spec.id]
        pos = tuple(_r(v) for v in initial_poses[i, :3])
        q = np.asarray(initial_poses[i, 3:], dtype=float)
        q = q / np.linalg.norm(q)
        if q[3] < 0:
            q = -q
        objects.append(replace(spec, position=spec.position if spec.static else pos,
                               orientation=spec.orientation if spec.static else tuple(_r(v) for v in q),
                               mass=nom.mass, friction=nom.friction, rolling_friction=nom.rolling_friction,
                               spinning_friction=nom.spinning_friction, restitution=nom.restitution))
    return replace(variant.scene.with_objects(objects), source=None)


@contextlib.contextmanager
def open_simulation(scenario: Scenario | str, seed: int = 0, duration: float | None = None,
                    settings: PhysicsSettings | None = None) -> Iterator[tuple[SimulationResult, GroundTruth]]:
    """Run ``scenario`` as :func:`simulate` does and keep its ground-truth world open while in the
    ``with`` block: yields ``(result, truth)``, ``truth`` being the :class:`GroundTruth` in its final
    state (hand and torso included), e.g. to ask what another camera would see at the end."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if duration is not None and not (duration > 0 and math.isfinite(duration)):
        raise InputError(f"duration must be > 0, got {duration}", field="duration")
    length = scenario.duration if duration is None else float(duration)
    variant = sample_variant(scenario, seed)
    perception_rng = np.random.default_rng([int(seed), 1])
    with GroundTruth(variant, settings) as gt:
        result = gt.run(length, perception_rng)
        _fill_result(result, scenario, seed, variant, gt, length)
        yield result, gt


def _fill_result(result: SimulationResult, scenario: Scenario, seed: int, variant: Variant, gt: GroundTruth,
                 length: float) -> None:
    """Fill ``result.scene`` (the estimator's scene) and ``result.meta`` (meta.json)."""
    result.scene = estimator_scene(variant, result.initial_poses)
    result.meta = {
        "format_version": FORMAT_VERSION,
        "scenario": scenario.name,
        "description": scenario.description,
        "source": scenario.name if scenario.builtin else scenario.source,
        "seed": int(seed),
        "duration": _r(length),
        "time_step": _r(gt.dt),
        "frames": len(result.truth),
        "observation_frames": len(result.observations),
        "perception": scenario.perception.to_dict(),
        "height_offsets": {oid: _r(v) for oid, v in zip(variant.scene.object_ids, result.height_offsets)},
        "sampled": _round_tree(variant.sampled),
        "true_dynamics": {o.id: {k: (None if getattr(o, k) is None else _r(getattr(o, k)))
                                 for k in ("mass", "friction", "rolling_friction", "spinning_friction",
                                           "restitution")} for o in variant.scene.objects},
        "events": result.events,
        "hands_tracked": scenario.perception.hands_tracked,
        "warnings": result.warnings,
        "files": ["scene.yaml", "observations.jsonl", "truth.jsonl", "meta.json"],
    }


def simulate(scenario: Scenario | str, seed: int = 0, duration: float | None = None,
             settings: PhysicsSettings | None = None) -> SimulationResult:
    """Run ``scenario`` (object or name/path) for ``seed``; ``duration`` (s) overrides the file's."""
    with open_simulation(scenario, seed, duration, settings) as (result, _truth):
        return result


def _round_tree(x):
    if isinstance(x, dict):
        return {k: _round_tree(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_round_tree(v) for v in x]
    if isinstance(x, float):
        return _r(x)
    return x


def _jsonl(rows: list[dict]) -> str:
    return "".join(json.dumps(r, allow_nan=False) + "\n" for r in rows)


def write_outputs(result: SimulationResult, out_dir: str | os.PathLike, *, prefix: str = "") -> dict[str, Path]:
    """Write ``scene.yaml``, ``observations.jsonl``, ``truth.jsonl`` and ``meta.json`` (each name
    preceded by ``prefix``) into ``out_dir`` (created if needed). Returns the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    texts = {
        "scene.yaml": yaml.safe_dump(scene_to_dict(result.scene), sort_keys=False, default_flow_style=None,
                                     width=100),
        "observations.jsonl": _jsonl(result.observations),
        "truth.jsonl": _jsonl(result.truth),
        "meta.json": json.dumps(result.meta, indent=2, allow_nan=False) + "\n",
    }
    paths = {}
    for name, text in texts.items():
        p = out / f"{prefix}{name}"
        with open(p, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        paths[name] = p
    return paths


def run_scenario(scenario: Scenario | str, seed: int, out_dir: str | os.PathLike,
                 duration: float | None = None) -> SimulationResult:
    """:func:`simulate` then :func:`write_outputs`."""
    result = simulate(scenario, seed, duration)
    write_outputs(result, out_dir)
    return result


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    """Read a JSON Lines file written by :func:`write_outputs`."""
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
