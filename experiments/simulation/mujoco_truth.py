"""A second ground truth: the scenario's world simulated by MuJoCo instead of Bullet.

The estimator's particles are pybullet worlds; a truth simulated by the same engine, time step and
collision shapes flatters it. :class:`MujocoGroundTruth` runs the same scenario variant (same
objects, scripted hand, camera and tracker) with MuJoCo's own contact model: soft contacts, an
elliptic friction cone with torsional and rolling friction, an implicit integrator, at
:data:`~experiments.simulation.mujoco_model.TIME_STEP`. A kinematic *mirror*, the pybullet
:class:`~physics.world.World` of :class:`~experiments.simulation.ground_truth.GroundTruth`, is set
to MuJoCo's poses before it is read, so that the truth's visibility (ray casts of the synthetic
camera), relations (bounding boxes), contacts (a Place or a Release) and pushes are computed by the
same code for both engines. The mirror is never stepped.

The MuJoCo world itself (geometry, masses, the hand's welds, contact parameters) is built by
:mod:`experiments.simulation.mujoco_model`. Quaternions in MuJoCo are ``(w, x, y, z)``; everything
this module returns uses ``(x, y, z, w)``.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from experiments.simulation.ground_truth import GroundTruth
from experiments.simulation.mujoco_model import (
    OBJECT_BITS,
    _wxyz,
    mjcf,
    object_geoms,
    restitution_damping,
    urdf_centre_of_mass,
)
from experiments.simulation.variants import Variant
from physics.errors import InputError
from physics.scene import Scene


class MujocoGroundTruth(GroundTruth):
    """:class:`~experiments.simulation.ground_truth.GroundTruth` whose bodies MuJoCo moves (see the
    module docstring); the pybullet world it holds is MuJoCo's kinematic mirror. Use as a context
    manager, as the Bullet truth."""

    def __init__(self, variant: Variant, settings=None):
        import mujoco  # a core dependency; imported here so that Bullet-only use never loads it

        self._mj = mujoco
        self.variant = variant
        self._dirty = True
        parked = _parked_poses(len(variant.scene.objects))
        try:
            self.model = mujoco.MjModel.from_xml_string(mjcf(variant, parked))
        except ValueError as exc:
            raise InputError(f"MuJoCo could not build the world: {exc}",
                             path=variant.scenario.source) from None
        self.data = mujoco.MjData(self.model)
        name = lambda kind, n: mujoco.mj_name2id(self.model, kind, n)  # noqa: E731
        m = len(variant.scene.objects)
        self._bodies = np.array([name(mujoco.mjtObj.mjOBJ_BODY, f"obj{i}") for i in range(m)])
        self._dynamic = np.array([not s.static for s in variant.scene.objects])
        self._qadr = {i: int(self.model.jnt_qposadr[self.model.body_jntadr[self._bodies[i]]])
                      for i in range(m) if self._dynamic[i]}
        self._geoms = {i: np.flatnonzero(self.model.geom_bodyid == self._bodies[i]) for i in range(m)}
        self._set_masses(variant.scene)
        self._hand_body = name(mujoco.mjtObj.mjOBJ_BODY, "hand")
        self._hand_geom = name(mujoco.mjtObj.mjOBJ_GEOM, "hand_geom")
        self._grasp_eq = {i: name(mujoco.mjtObj.mjOBJ_EQUALITY, f"grasp{i}") for i in range(m) if self._dynamic[i]}
        if self._hand_body >= 0:  # the broad phase filters bodies by the OR of their geoms' bits
            self.model.body_contype[self._hand_body] = 2
        super().__init__(variant, settings)

    def _set_masses(self, scene: Scene) -> None:
        """Each dynamic body's mass to the scene's, its inertia scaled with it (uniform density); a
        URDF object's centre of mass where its URDF states it (:func:`urdf_centre_of_mass`; the
        inertia stays the geometry's, as pybullet does)."""
        for i, spec in enumerate(scene.objects):
            if spec.static:
                continue
            _geoms, mass = object_geoms(spec)
            b = self._bodies[i]
            ratio = mass / max(float(self.model.body_mass[b]), 1e-12)
            self.model.body_mass[b] *= ratio
            self.model.body_inertia[b] *= ratio
            com = urdf_centre_of_mass(spec.urdf, float(spec.scale)) if spec.shape == "urdf" else None
            if com is not None:
                self.model.body_ipos[b] = com
        self._mj.mj_setConst(self.model, self.data)

    # -- the engine ---------------------------------------------------------------------------------
    def _time_step(self) -> float:
        return float(self.model.opt.timestep)

    def _step(self) -> None:
        self._mj.mj_step(self.model, self.data)
        self._dirty = True

    def _sync(self) -> None:
        """Set the mirror's dynamic objects and hand to MuJoCo's poses and recompute its contacts."""
        if not self._dirty or getattr(self, "world", None) is None:
            return
        mj = self._mj
        mj.mj_kinematics(self.model, self.data)
        idx = np.flatnonzero(self._dynamic)
        if len(idx):
            self.world.set_poses(self._poses(idx), idx)
        if self.hand_uid >= 0:
            p = self.data.xpos[self._hand_body]
            q = self.data.xquat[self._hand_body]
            pb.resetBasePositionAndOrientation(self.hand_uid, p.tolist(), [q[1], q[2], q[3], q[0]],
                                               physicsClientId=self.world.client)
        pb.performCollisionDetection(physicsClientId=self.world.client)
        self._dirty = False

    def _poses(self, idx) -> np.ndarray:
        """MuJoCo's link-frame poses ``(n, 7)`` (x, y, z, w quaternions) of objects ``idx``."""
        b = self._bodies[idx]
        q = self.data.xquat[b]
        return np.concatenate([self.data.xpos[b], q[:, 1:], q[:, :1]], axis=1)

    def _drive_hand(self, t: float) -> None:
        p, q = self.segment.at(t)
        self.data.mocap_pos[0] = p + self.hand_shift
        self.data.mocap_quat[0] = _wxyz(q)

    def _set_collide(self, on: bool) -> None:
        super()._set_collide(on)
        self.model.geom_contype[self._hand_geom] = 2 if on else 0

    def _grasp(self, index: int, step: int, event: bool = True, where: str = "hand.holding") -> None:
        super()._grasp(index, step, event, where)
        mj = self._mj
        mj.mj_kinematics(self.model, self.data)
        hp, hq = self.data.xpos[self._hand_body], self.data.xquat[self._hand_body]
        b = self._bodies[index]
        inv = np.empty(4)
        mj.mju_negQuat(inv, hq)
        rel_p = np.empty(3)
        mj.mju_rotVecQuat(rel_p, self.data.xpos[b] - hp, inv)
        rel_q = np.empty(4)
        mj.mju_mulQuat(rel_q, inv, self.data.xquat[b])
        k = self._grasp_eq[index]
        self.model.eq_data[k, :3] = 0.0
        self.model.eq_data[k, 3:6] = rel_p
        self.model.eq_data[k, 6:10] = rel_q
        self.model.eq_data[k, 10] = 1.0
        self.data.eq_active[k] = 1
        self.model.geom_conaffinity[self._geoms[index]] = OBJECT_BITS[1] & ~2

    def _release(self, index: int, step: int) -> None:
        self.data.eq_active[self._grasp_eq[index]] = 0
        self.model.geom_conaffinity[self._geoms[index]] = OBJECT_BITS[1]
        super()._release(index, step)

    def perturb(self, index: int, offset, params: dict[str, float] | None = None) -> None:
        """As :meth:`GroundTruth.perturb`, in MuJoCo (the mirror follows at the next read)."""
        if params:
            geoms = self._geoms[index]
            for col, key in ((0, "friction"), (1, "spinning_friction"), (2, "rolling_friction")):
                if params.get(key) is not None:
                    self.model.geom_friction[geoms, col] = float(params[key])
            if params.get("restitution") is not None:
                self.model.geom_solref[geoms, 1] = restitution_damping(params["restitution"])
            if params.get("mass") is not None:
                b = self._bodies[index]
                ratio = float(params["mass"]) / float(self.model.body_mass[b])
                self.model.body_mass[b] *= ratio
                self.model.body_inertia[b] *= ratio
                qpos = self.data.qpos.copy()  # mj_setConst puts qpos at the model's qpos0: keep the run's
                self._mj.mj_setConst(self.model, self.data)
                self.data.qpos[:] = qpos
                self._mj.mj_forward(self.model, self.data)
        offset = np.asarray(offset, dtype=float)
        if index in self.held:
            self.hand_shift = self.hand_shift + offset
            return
        a = self._qadr[index]
        self.data.qpos[a:a + 3] += offset
        self._dirty = True


def _parked_poses(m: int) -> np.ndarray:
    """The poses :class:`~physics.world.World` parks unposed objects at (its ``parked_pose``)."""
    from physics.world import PARK_DISTANCE
    out = np.zeros((m, 7))
    out[:, 0] = PARK_DISTANCE + 3.0 * np.arange(m)
    out[:, 1] = PARK_DISTANCE
    out[:, 2] = -PARK_DISTANCE
    out[:, 6] = 1.0
    return out
