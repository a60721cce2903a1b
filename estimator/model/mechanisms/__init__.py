"""The scene model's mechanisms: each one way objects move, or are let go, before physics runs.

K particles, M objects; positions in metres, quaternions ``(x, y, z, w)``, times in seconds.

The scene model (:class:`~estimator.model.SceneModel`) builds each update's motion from a list of
mechanisms (:func:`mechanisms_for`): the paper's reasoner is a short list, the full model a longer
one, and a new mechanism is one module here and one entry in that list. A mechanism is a
:class:`Mechanism`: it may declare per-particle arrays (:attr:`Mechanism.arrays`, which the particle
state holds and resampling takes with the others without knowing them) and has hooks, one per
*phase* of an update's proposal, run in the order of :data:`PHASES` and, within a phase, in the order
of the list. Each hook reads and writes the update's :class:`Draft`:

* ``perceive``: what the perception says before anything else moves (teleports, Alg. 2);
* ``release``: held objects let go (release on loss, behind cover, in motion);
* ``let_go``: the velocities of what was let go;
* ``rest``: resting objects fused with their detections;
* ``target``: where held objects go, and what the physics checks (the divergence test's targets);
* ``noise``: process noise on what nobody sees;
* ``check``: the targets' last corrections before physics (static geometry).

After physics, :meth:`Mechanism.after_physics` runs in list order on the worlds' output, before the
model's relations and events; once the update is weighed, :meth:`Mechanism.commit` hands the
model the mechanism's arrays after the update (the loop's own arrays are the state's). A mechanism
needs what the draft holds, or adds a field to it; the others do not know it exists (taken off the
list, it is gone and nothing else breaks: ``tests/test_mechanisms.py``).
"""
from __future__ import annotations

from .base import PHASES, Draft, Mechanism
from .cover import LetGoBehindCover
from .deceleration import DecelerationEvidence
from .flick import LetGoMoving
from .follow_hand import FollowHands
from .process_noise import ProcessNoise
from .release import ReleaseOnLoss
from .rest_fusion import FusionAtRest
from .static_clip import StaticClip
from .teleport import Teleports
from .velocity import VelocityEvidence

__all__ = ["PHASES", "Draft", "Mechanism", "mechanisms_for"]


def mechanisms_for(model) -> list[Mechanism]:
    """The mechanisms of ``model`` (a :class:`~estimator.model.SceneModel`) under its configuration,
    in the order their hooks run. The paper's reasoner (:meth:`~estimator.config.EstimatorConfig.paper`)
    has teleports (at rest), release on loss, let go behind cover (inert with ``hand_occlusion`` 1),
    following a hand and process noise (none with its noise off); the full model adds velocity
    and deceleration evidence, let go in motion, fusion at rest and static clipping. A new mechanism goes here."""
    cfg = model.config
    moving = cfg.moving_teleports
    out: list[Mechanism] = [Teleports(model, moving=moving)]
    if moving and cfg.noise.velocity_slack > 0:
        out.append(VelocityEvidence(model))
    if moving and cfg.noise.decel_error > 0:
        out.append(DecelerationEvidence(model))
    out += [ReleaseOnLoss(model, left_view=moving), LetGoBehindCover(model)]
    if cfg.priors.let_go_moving > 0:
        out.append(LetGoMoving(model))
    if cfg.noise.fuse_resting:
        out.append(FusionAtRest(model))
    out += [FollowHands(model, moving=moving), ProcessNoise(model)]
    if model.geometry is not None:
        out.append(StaticClip(model))
    return out
