"""No object inside static geometry (``static_clip``): the path of a held object to its target stops
at the surface of static geometry it would enter (a hand cannot carry a cup through the table); the
target of a free one checked against its detection, sunk into static geometry by the tracker's error,
is pushed out of it (it is not where the cup is: the cup is on the surface, above it); after physics,
an object that a step left inside the table or the floor is pushed out
(:class:`~physics.penetration.StaticGeometry`)."""
from __future__ import annotations

import numpy as np

from actions.modes import is_held
from physics.penetration import CLIP_DEPTH

from .base import Draft, Mechanism


class StaticClip(Mechanism):
    """Clips :attr:`Draft.target` before physics and pushes the poses out of static geometry after."""

    def check(self, u: Draft) -> None:
        held = is_held(u.modes)
        self.clip_targets(u.poses, u.target, u.target_vel, held)
        self.lift_targets(u.target, u.target_vel, u.check & ~held)

    def lift_targets(self, target: np.ndarray, target_vel: np.ndarray, which: np.ndarray) -> None:
        """In place on ``target (K, M, 7)`` and ``target_vel (K, M, 6)``: the targets of the entries
        ``which (K, M)`` more than :data:`~physics.penetration.CLIP_DEPTH` deep inside static geometry
        are pushed out of it along the deepest contact's normal
        (:meth:`~physics.penetration.StaticGeometry.push_out`, which asks equal targets once) and
        have no target velocity. The detection's horizontal position is kept, which a path stopped at
        the surface from each particle's pose would cut short; and it costs one query per distinct
        target, not a sweep per particle."""
        model = self.model
        for m in np.flatnonzero(which.any(axis=0) & model.dynamic & model.known).tolist():
            rows = np.flatnonzero(which[:, m])
            lifted, deep = model.geometry.push_out(m, target[rows, m], CLIP_DEPTH)
            if np.any(deep):
                target[rows[deep], m] = lifted[deep]
                target_vel[rows[deep], m] = 0.0

    def clip_targets(self, poses: np.ndarray, target: np.ndarray, target_vel: np.ndarray, which: np.ndarray) -> None:
        """In place on ``target (K, M, 7)`` and ``target_vel (K, M, 6)``: the paths of the entries
        ``which (K, M)`` from ``poses`` to their targets stop at the surface of static geometry they
        would enter (:meth:`~physics.penetration.StaticGeometry.clip`), and those stopped have no target
        velocity."""
        model = self.model
        for m in np.flatnonzero(which.any(axis=0) & model.dynamic & model.known).tolist():
            rows = np.flatnonzero(which[:, m])
            end, frac = model.geometry.clip(m, poses[rows, m], target[rows, m])
            stopped = ~(frac == 1.0)
            if np.any(stopped):
                target[rows[stopped], m] = end[stopped]
                target_vel[rows[stopped], m] = 0.0

    def after_physics(self, poses: np.ndarray, aabbs: np.ndarray) -> np.ndarray:
        """``poses (K, M, 7)`` after physics with the known dynamic objects more than
        :data:`~physics.penetration.INVARIANT_DEPTH` deep inside static geometry pushed out of it
        (:meth:`~physics.penetration.StaticGeometry.push_out`; a box test on ``aabbs (K, M, 2, 3)``
        leaves out, cheaply, every object that cannot be that deep,
        :meth:`~physics.penetration.StaticGeometry.may_be_inside`): a step can end in the middle of an
        impact (a cup that fell 70 cm reaches the floor at 3.7 m/s, 1.5 cm per step), and a stack
        whose blocks the prior perturbed apart is pressed into its support while the blocks separate;
        no particle may report an object inside the table or the floor. A new array when any moves;
        the worlds reload them at the next update (they differ from what the worlds hold)."""
        model = self.model
        geometry = model.geometry
        check = (model.dynamic & model.known)[None, :] & geometry.may_be_inside(aabbs)
        if not np.any(check):
            return poses
        out = poses
        for m in np.flatnonzero(check.any(axis=0)).tolist():
            rows = np.flatnonzero(check[:, m])
            moved, deep = geometry.push_out(m, poses[rows, m])
            if np.any(deep):
                out = poses.copy() if out is poses else out
                out[rows[deep], m] = moved[deep]
        return out
