"""The parts every mechanism shares: the update's :class:`Draft`, the :class:`Mechanism` base and its
declared arrays (:class:`ArraySpec`), the :data:`PHASES` (see :mod:`estimator.model.mechanisms`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.modes import is_free, is_held

from ...state import ArraySpec

__all__ = ["PHASES", "Draft", "Mechanism"]

PHASES = ("perceive", "release", "let_go", "rest", "target", "noise", "check")
"""The phases of an update's proposal, in the order they run."""


@dataclass
class Draft:
    """The working arrays of one update's proposal, which the mechanisms' hooks read and write.

    Inputs: ``state`` (:class:`~estimator.state.ParticleState` before the update), ``frame`` (the
    newest), ``detected (M,)`` since the last update, ``perceived (M,)`` now, ``dt`` (s), ``rng``,
    ``cameras`` (None: the scene's). Perception read once for all (:mod:`estimator.model.perception_memory`):
    ``tick_vel (M, 3)`` m/s, ``following (M,)`` (detected in a tracked hand), ``far (M,)`` (detected
    out of reach of every tracked hand; None: no hand tracked or hands not followed).

    Working arrays (see :class:`~estimator.model.step.Move` for their meaning): ``poses``, ``vel``,
    ``prev_modes``, ``modes``, ``release_codes``, ``predicted``, ``jitter``, ``tele``, ``newly_known``,
    ``level (M,)`` (teleported horizontally only: first sightings within the tracker's noise of
    where the scene places them, each particle keeping its height and orientation),
    ``moving`` and ``falling (M,)``, ``start (M, 3)``, ``fall`` (:class:`~estimator.model.step.Fall`),
    ``set_moving``, ``cover_t``, ``proposal (K,)``, ``grip``,
    ``let_go``, ``resting``, ``nudged``, ``detections``, ``target``, ``target_vel``,
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
    level: np.ndarray | None = None
    start: np.ndarray | None = None
    fall: object = None
    set_moving: np.ndarray | None = None
    modes: np.ndarray | None = None
    release_codes: np.ndarray | None = None
    cover_t: np.ndarray | None = None
    proposal: np.ndarray | None = None
    grip: np.ndarray | None = None
    let_go: np.ndarray | None = None
    resting: np.ndarray | None = None
    nudged: np.ndarray | None = None
    detections: np.ndarray | None = None
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
        return is_held(self.prev_modes) & is_free(self.modes)


class Mechanism:
    """One mechanism of the scene model, bound to it (``model``: its scene, configuration, perception
    memory and static geometry). Subclasses override the hooks they need; the others do nothing.

    ``arrays``: the per-particle arrays it keeps in the particle state, by name."""

    arrays: dict[str, ArraySpec] = {}

    def __init__(self, model):
        self.model = model

    def commit(self, state, p, w, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """The mechanism's arrays (:attr:`arrays`) after the update, by name: ``state`` before it,
        ``p`` its :class:`~estimator.model.step.Proposal`, ``w`` its :class:`~estimator.model.step.Weighed`.
        Those it leaves out keep their values (an array changed in place stays changed)."""
        return {}

    def terms(self) -> tuple:
        """The mechanism's own terms of the log-weight (callables ``term(evidence) -> (K,)``,
        :mod:`estimator.model.terms`), added after those of every model."""
        return ()

    def after_weighing(self, ev, log_weights: np.ndarray) -> None:
        """Once the terms are summed: the update's evidence ``ev``
        (:class:`~estimator.model.terms.Evidence`) and the new log-weights ``log_weights (K,)`` (-inf
        for exploded particles), e.g. to track how far the particles are from what was perceived."""

    def after_physics(self, poses: np.ndarray, aabbs: np.ndarray) -> np.ndarray:
        """The particles' poses ``(K, M, 7)`` after physics (``aabbs (K, M, 2, 3)``), corrected (the
        same array when nothing changes)."""
        return poses
