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
model's relations and events.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.modes import FREE, HELD

__all__ = ["PHASES", "ArraySpec", "Draft", "Mechanism", "mechanisms_for"]

PHASES = ("perceive", "release", "let_go", "rest", "target", "noise", "check")
"""The phases of an update's proposal, in the order they run."""


@dataclass(frozen=True)
class ArraySpec:
    """A per-particle array a mechanism declares: shape ``(K, M) + tail``, ``dtype`` and the value it
    starts with (``fill``)."""

    tail: tuple = ()
    dtype: type = float
    fill: float = 0.0


@dataclass
class Draft:
    """The working arrays of one update's proposal, which the mechanisms' hooks read and write.

    Inputs: ``state`` (:class:`~estimator.state.ParticleState` before the update), ``frame`` (the
    newest), ``detected (M,)`` since the last update, ``perceived (M,)`` now, ``dt`` (s), ``rng``,
    ``cameras`` (None: the scene's). Perception read once for all (:mod:`estimator.perception_memory`):
    ``tick_vel (M, 3)`` m/s, ``following (M,)`` (detected in a tracked hand), ``far (M,)`` (detected
    out of reach of every tracked hand; None: no hand tracked or hands not followed).

    Working arrays (see :class:`~estimator.step.Move` for their meaning): ``poses``, ``vel``,
    ``prev_modes``, ``modes``, ``release_codes``, ``predicted``, ``jitter``, ``tele``, ``newly_known``,
    ``moving``, ``falling`` and ``spinning (M,)``, ``start (M, 3)``, ``fall`` (:class:`~estimator.step.Fall`),
    ``set_moving``, ``speed_check``, ``left_view (M,)``, ``cover_t``, ``proposal (K,)``, ``grip``,
    ``let_go``, ``resting``, ``nudged``, ``detections``, ``stale``, ``target``, ``target_vel``,
    ``hold_error``, ``jolted``, ``check``."""

    state: object
    frame: object
    detected: np.ndarray
    perceived: np.ndarray
    dt: float
    rng: np.random.Generator
    cameras: tuple | None
    tick_vel: np.ndarray
    following: np.ndarray
    far: np.ndarray | None
    poses: np.ndarray
    vel: np.ndarray
    prev_modes: np.ndarray
    predicted: np.ndarray
    jitter: np.ndarray
    newly_known: np.ndarray
    tele: np.ndarray
    moving: np.ndarray
    falling: np.ndarray
    spinning: np.ndarray
    start: np.ndarray | None = None
    fall: object = None
    set_moving: np.ndarray | None = None
    speed_check: tuple | None = None
    modes: np.ndarray | None = None
    release_codes: np.ndarray | None = None
    left_view: np.ndarray | None = None
    cover_t: np.ndarray | None = None
    proposal: np.ndarray | None = None
    grip: np.ndarray | None = None
    let_go: np.ndarray | None = None
    resting: np.ndarray | None = None
    nudged: np.ndarray | None = None
    detections: np.ndarray | None = None
    stale: np.ndarray | None = None
    target: np.ndarray | None = None
    target_vel: np.ndarray | None = None
    hold_error: np.ndarray | None = None
    jolted: np.ndarray | None = None
    check: np.ndarray | None = None

    @property
    def t(self) -> float:
        return self.frame.t

    @property
    def cover(self) -> np.ndarray:
        """``(K, M)`` bool: the objects let go behind cover now."""
        return np.isfinite(self.cover_t)

    @property
    def let_go_now(self) -> np.ndarray:
        """``(K, M)`` bool: held at the last update, free now."""
        return (self.prev_modes == HELD) & (self.modes == FREE)


class Mechanism:
    """One mechanism of the scene model, bound to it (``model``: its scene, configuration, perception
    memory and static geometry). Subclasses override the hooks they need; the others do nothing.

    ``arrays``: the per-particle arrays it keeps in the particle state, by name."""

    arrays: dict[str, ArraySpec] = {}

    def __init__(self, model):
        self.model = model

    def after_physics(self, poses: np.ndarray, aabbs: np.ndarray) -> np.ndarray:
        """The particles' poses ``(K, M, 7)`` after physics (``aabbs (K, M, 2, 3)``), corrected (the
        same array when nothing changes)."""
        return poses


def mechanisms_for(model) -> list[Mechanism]:
    """The mechanisms of ``model`` (a :class:`~estimator.model.SceneModel`) under its configuration,
    in the order their hooks run: the paper's reasoner (``moving_teleports`` off) teleports and
    follows its perception only; the full model adds the rest. A new mechanism goes here."""
    from .cover import LetGoBehindCover
    from .flick import LetGoMoving
    from .follow_hand import FollowHands
    from .process_noise import ProcessNoise
    from .release import ReleaseOnLoss
    from .rest_fusion import FusionAtRest
    from .static_clip import StaticClip
    from .teleport import Teleports
    from .velocity import VelocityEvidence

    cfg = model.config
    out: list[Mechanism] = [Teleports(model)]
    if cfg.moving_teleports and cfg.noise.velocity_slack > 0:
        out.append(VelocityEvidence(model))
    out += [ReleaseOnLoss(model), LetGoBehindCover(model)]
    if cfg.priors.let_go_moving > 0:
        out.append(LetGoMoving(model))
    if cfg.noise.fuse_resting:
        out.append(FusionAtRest(model))
    out += [FollowHands(model), ProcessNoise(model)]
    if model.geometry is not None:
        out.append(StaticClip(model))
    return out
