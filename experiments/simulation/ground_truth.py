"""The ground-truth world of a scenario's variant: the scene's objects, a scripted hand (a dynamic
sphere pulled along its script by a constraint, :mod:`experiments.simulation.scripted_hand`), an
optional torso and the synthetic camera, stepped at 240 Hz; it records the truth and what the
faulty tracker reports (see :mod:`experiments.simulation.simulator` for the whole run and the
truth's events)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pybullet as pb

from estimator.relations import relation_list, relation_masks
from estimator.worlds.resting import at_rest
from experiments.simulation.camera import SyntheticCamera
from experiments.simulation.files import SimulationResult, _r, _rl
from experiments.simulation.perception import PerceptionModel
from experiments.simulation.pushes import PUSH_GAP, PushTracker
from experiments.simulation.scripted_hand import ScriptedHand
from experiments.simulation.variants import Variant
from physics.bodies import bullet_rolling_friction, support_friction
from physics.scene import CameraSpec
from physics.world import PhysicsSettings, World

HAND_ID = "human/right"
SETTLE_WINDOW = 0.05
"""s: after the scenario's ``settle`` time the truth goes on settling, by windows of this length,
until no dynamic object moved faster than the particle worlds' at-rest speed and spin
(:data:`~estimator.worlds.resting.REST_SPEED`, :data:`~estimator.worlds.resting.REST_SPIN`) over
the last window (a duck dropped onto the table still rocks after 0.3 s: handed to the estimator
mid-swing, it is a pose no object rests in)."""
SETTLE_MAX = 3.0
"""s: the most the truth settles beyond the scenario's ``settle`` time (then t = 0, at rest or not)."""


# --------------------------------------------------------------------------------------------------
# the ground-truth world


class GroundTruth(ScriptedHand):
    """The true world of a variant: scene objects, hand, torso and camera, stepped at 240 Hz (the
    hand's building, driving, grasps, releases and pushes:
    :class:`~experiments.simulation.scripted_hand.ScriptedHand`).

    Use as a context manager (it owns a pybullet client). :meth:`run` simulates the whole scenario.
    """

    def __init__(self, variant: Variant, settings: PhysicsSettings | None = None):
        self.variant = variant
        self.scenario = variant.scenario
        self.world = World(variant.scene, settings or PhysicsSettings())
        self.dt = self._time_step()
        self.hand_uid = -1
        self.torso_uid = -1
        self.held: dict[int, int] = {}  # object index -> constraint id
        self.collide = False
        self.events: list[tuple[int, dict]] = []  # (step, event)
        self.pushes = PushTracker(int(round(PUSH_GAP / self.dt)))
        self.warnings: list[str] = []
        self.hand_shift = np.zeros(3)  # m, added to the hand's scripted path (see :meth:`perturb`)
        # m: the rolling friction each dynamic object states (None: none), and what Bullet is given
        # for it on the support it rests on now (:meth:`_realise_rolling`)
        self.rolling = {i: s.rolling_friction for i, s in enumerate(variant.scene.objects)
                        if not s.static and s.rolling_friction is not None}
        self._given_rolling = dict(self.rolling)
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

    # -- the engine that moves the bodies (Bullet: this world itself; see also
    # experiments.simulation.mujoco_truth, whose engine moves them and this world mirrors it) ------
    def _time_step(self) -> float:
        """s: the truth's simulation step."""
        return self.world.settings.time_step

    def _step(self) -> None:
        """Advance the truth by one step of :attr:`dt`, then give each object that states a rolling
        friction what Bullet needs to realise it on the support it now rests on."""
        self.world.step(1)
        self._realise_rolling()

    def _realise_rolling(self) -> None:
        """The scene's rolling friction is a contact's resisting torque per newton of normal force
        on any support (as MuJoCo realises it); Bullet scales a body's by its support's lateral
        friction (:func:`physics.bodies.bullet_rolling_friction`). Set from the last step's contacts;
        an object resting on nothing keeps what it had."""
        c = self.world.client
        for i, stated in self.rolling.items():
            mu = support_friction(c, self.world.uids[i])
            if not math.isfinite(mu):
                continue
            given = float(bullet_rolling_friction(stated, mu))
            if given != self._given_rolling[i]:
                self.world.set_dynamics(i, rolling_friction=given)
                self._given_rolling[i] = given

    def _sync(self) -> None:
        """Bring this world (poses, contacts) up to date before it is read (nothing to do when it is
        the engine itself)."""

    # -- bodies -------------------------------------------------------------------------------------
    def _all_bodies(self) -> list[tuple[int, int]]:
        """(uid, link) of every scene body and link, and the floor."""
        c = self.world.client
        out = [(self.world.floor_uid, -1)] if self.world.floor_uid >= 0 else []
        for uid in self.world.uids:
            out.extend((uid, link) for link in range(-1, pb.getNumJoints(uid, physicsClientId=c)))
        return out

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

    # -- events and perturbations (the hand's actions: ScriptedHand) -------------------------------
    def _event(self, step: int, action: str, index: int) -> None:
        self.events.append((step, {"t": _r(step * self.dt), "action": action,
                                   "subject": self.world.object_ids[index], "p": 1.0}))

    def perturb(self, index: int, offset, params: dict[str, float] | None = None) -> None:
        """Move object ``index`` by ``offset (3,)`` m now, its velocity kept; an object in the hand
        moves with the hand instead: the hand's path is shifted by ``offset`` from now on (what a
        twin of the run, :mod:`experiments.evaluation.predictability`, changes at an object's last
        sighting). ``params``: physical parameters the object has from now on (``mass`` kg,
        ``friction``, ``rolling_friction``, ``spinning_friction``, ``restitution``; others kept)."""
        if params:
            if params.get("rolling_friction") is not None and not self.world.static[index]:
                self.rolling[index] = float(params["rolling_friction"])  # realised at the next step
                self._given_rolling[index] = math.nan
            self.world.set_dynamics(index, lateral_friction=params.get("friction"),
                                    rolling_friction=params.get("rolling_friction"),
                                    spinning_friction=params.get("spinning_friction"),
                                    restitution=params.get("restitution"), mass=params.get("mass"))
        offset = np.asarray(offset, dtype=float)
        if index in self.held:
            self.hand_shift = self.hand_shift + offset
            return
        pose = self.world.get_poses([index])
        pose[0, :3] += offset
        self.world.set_poses(pose, [index])


    # -- the run ------------------------------------------------------------------------------------
    def settle(self) -> None:
        """Simulate ``scenario.settle`` seconds with the hand at its start, then on until the dynamic
        objects are at rest (:data:`SETTLE_WINDOW`, at most :data:`SETTLE_MAX` more); the state
        reached is t = 0."""

        def steps(n: int) -> None:
            for _ in range(n):
                if self.hand_uid >= 0:
                    self._drive_hand(0.0)
                self._step()

        n = int(round(self.scenario.settle / self.dt))
        window = max(1, int(round(SETTLE_WINDOW / self.dt)))
        steps(max(0, n - window))  # the settle time's last window is the first one tested
        for _ in range(int(round(SETTLE_MAX / SETTLE_WINDOW)) + (n >= window)):
            before = self._dynamic_poses()
            steps(window)
            if at_rest(before, self._dynamic_poses(), window * self.dt):
                break
        if self.hand_uid >= 0:
            self._start_segment(0.0)
            self._advance_script(0.0, 0)

    def _dynamic_poses(self) -> np.ndarray:
        """Poses ``(D, 7)`` of the scene's dynamic objects, as the truth has them now."""
        self._sync()
        return self.world.get_poses(self.world.dynamic_indices)

    def look(self, camera: CameraSpec) -> np.ndarray:
        """Visible fractions ``(M,)`` of every object to ``camera`` in the world's present state
        (hand and torso occlude; the scenario's sample points and nothing else changed)."""
        self._sync()
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

    def run(self, duration: float, perception_rng: np.random.Generator,
            perturbations: dict[int, list[tuple]] | None = None) -> "SimulationResult":
        """Settle, then simulate ``duration`` seconds; returns the recorded streams.
        ``perturbations``: ``{step: [(object index, offset (3,) m, params or None), ...]}`` applied by
        :meth:`perturb` after that simulation step (1-based) and the script's waypoints due then."""
        cfg = self.scenario.perception
        world = self.world
        self.settle()
        self._sync()
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
            self._sync()
            poses = world.get_poses()
            frac = self.visible_fractions(poses)
            return poses, frac, self.hand_position()

        if 0 in captures:
            snapshots[0] = snapshot()
        for step in range(1, n_steps + 1):
            t = step * self.dt
            if self.hand_uid >= 0:
                self._drive_hand(t)
            self._step()
            if self.hand_uid >= 0:
                self._advance_script(t, step)
                self._track_pushes(step)
            if perturbations and step in perturbations:
                for index, offset, params in perturbations[step]:
                    self.perturb(index, offset, params)
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
