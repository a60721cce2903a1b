"""The ground truth's scripted hand (:class:`ScriptedHand`, a mixin of
:class:`~experiments.simulation.ground_truth.GroundTruth`): a dynamic sphere built in the truth's
pybullet world and pulled along the scenario's script (:mod:`experiments.simulation.hand_path`) by a
fixed constraint; its grasps (a fixed constraint at the relative pose of the moment) and releases
(a Place when the object rests on a support, else a Release), whether it collides with objects, and
the objects it pushes (:mod:`experiments.simulation.pushes`). Units: metres, seconds; quaternions
``(x, y, z, w)``."""
from __future__ import annotations

import numpy as np
import pybullet as pb

from estimator.relations import relation_masks
from experiments.scenarios.specs import HandTarget
from experiments.simulation.hand_path import _quat_from_rpy, _Segment
from physics.errors import InputError
from physics.transforms import pose_compose, pose_inverse

GRASP_REACH = 0.04
"""A grasp needs the object's bounding box within hand radius + this distance (m) of the hand centre."""
CONTACT_DISTANCE = 0.003
"""At a release, an object with a contact closer than this (m) rests on a support (a Place)."""


class ScriptedHand:
    """The hand's part of the ground truth. The class it is mixed into provides ``world`` (the
    pybullet :class:`~physics.world.World`), ``scenario``, ``variant``, ``dt`` (s), ``hand_uid``
    (-1: no hand), ``held`` (object index -> constraint id), ``collide``, ``pushes`` (a
    :class:`~experiments.simulation.pushes.PushTracker`), ``hand_shift`` (m, ``(3,)``) and the
    methods ``_sync``, ``_all_bodies`` and ``_event``."""

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

    def _set_collide(self, on: bool) -> None:
        c = self.world.client
        held_uids = {self.world.uids[i] for i in self.held}
        for uid, link in self._all_bodies():
            enable = int(on and uid not in held_uids)
            pb.setCollisionFilterPair(self.hand_uid, uid, -1, link, enable, physicsClientId=c)
        self.collide = on

    def hand_position(self) -> np.ndarray | None:
        if self.hand_uid < 0:
            return None
        self._sync()
        p, _q = pb.getBasePositionAndOrientation(self.hand_uid, physicsClientId=self.world.client)
        return np.array(p, dtype=float)

    def _grasp(self, index: int, step: int, event: bool = True, where: str = "hand.holding") -> None:
        self._sync()
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
        self._sync()
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
        self._sync()
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

    def _resolve(self, target: HandTarget | None, previous: np.ndarray) -> np.ndarray:
        if target is None:
            return previous
        if target.position is not None:
            return np.asarray(target.position, dtype=float)
        if target.by is not None:
            return previous + np.asarray(target.by, dtype=float)
        self._sync()
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
        p = p + self.hand_shift
        pb.changeConstraint(self.hand_constraint, jointChildPivot=p.tolist(),
                            jointChildFrameOrientation=q.tolist(), maxForce=self.scenario.hand.max_force,
                            physicsClientId=self.world.client)
