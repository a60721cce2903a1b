"""What one update of the scene model hands on: the particles' motion before physics (:class:`Move`)
and their state after physics and the Place / Release rules (:class:`Settled`). K particles, M
objects; positions in metres, quaternions ``(x, y, z, w)``, times in seconds."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Fall:
    """Objects ``mask (M,)`` perceived falling off an edge, on the free fall through their last
    detections (:meth:`~estimator.model.perception_memory.PerceptionMemory.free_fall`): height ``z (M,)``
    (m) at the update's end and ``mean_vz (M,)`` (m/s) over the update (from where the fall had them
    at its start). Held objects are there (the divergence test's target moving on a line at the mean
    velocity: the fall's own chord, not the end velocity carried back); those let go now fall on at
    the free fall's velocity then (:meth:`~estimator.model.SceneModel.settle`)."""

    mask: np.ndarray
    z: np.ndarray
    mean_vz: np.ndarray


@dataclass(frozen=True)
class Move:
    """A particle's motion before physics in one update (K particles, M objects).

    ``poses (K, M, 7)`` / ``velocities (K, M, 6)``: the state handed to physics;
    ``predicted (K, M, 7)``: the poses before the teleports (what each particle expected; with
    moving teleports carried on over the update at its velocity, without the last teleport's noise);
    ``previous_modes`` / ``modes`` ``(K, M)`` int8: at the last update and after the releases;
    ``release_codes (K, M)`` int8: event codes of those releases; ``teleported (M,)`` bool;
    ``target (K, M, 7)`` / ``target_vel (K, M, 6)``: where held objects go and perceived objects
    are checked against; ``check (K, M)``: free objects to test for divergence; ``depenetrate (K, M)``:
    objects displaced without physics; ``vis_query (M,)``: objects whose visibility is wanted;
    ``hold_error (K, M, 3)``, ``let_go_unseen (K, M)``: see :class:`~estimator.state.ParticleState` (None
    without the mechanism that keeps them);
    ``cameras``: the cameras that took the frames of the update (None: the scene's camera);
    ``cover_t (K, M)``: when the objects let go now where their hand hid them earlier were let go
    (s, NaN elsewhere; :attr:`behind_cover` is the mask; :func:`~estimator.model.hidden.let_go_behind_cover`:
    put down where it was lowest, a Place, or dropped at a sampled hidden place), and
    ``proposal_log_weight (K,)`` the weight factor of that move and of the let-goes in motion
    (:func:`~estimator.model.motion.let_go_moving`); ``fused (K, M)`` bool: objects at rest moved towards
    their detection (:meth:`~estimator.model.mechanisms.rest_fusion.FusionAtRest.fuse_resting`; scored where the particle expected them);
    ``jitter (K, M, 3)``: the teleports' position noise (see :class:`~estimator.state.ParticleState`);
    ``out_of_reach (M,)``: objects detected out of reach of every tracked hand (None: no hand
    tracked; :class:`~estimator.model.terms.Evidence`); ``fall``: the objects perceived falling off
    an edge (:class:`Fall`; None: none); ``detections (M, 7)``: the latest detections, those made in
    an earlier frame of the update carried on to its end by their tracked hand, or, seen moving, at
    their velocity (:meth:`~estimator.model.perception_memory.PerceptionMemory.detections_now`; None: as
    detected); ``set_moving (K, M)`` bool: objects at rest in their particle, seen starting to move
    along their support with no tracked hand within reach, that go on at their perceived velocity
    (a Push by an agent nobody tracks, not a Pick; None: none); ``push_grip (K, M)``: see
    :class:`~estimator.state.ParticleState` (None: all NaN); ``placed_at_rest (K, M)`` bool: at the
    first update, the objects its placement left at rest where physics would keep them
    (:func:`~estimator.model.regularisation.placed_at_rest`; None: none), for the worlds to load
    asleep (:meth:`~estimator.worlds.pool.WorldPool.advance`).
    """

    poses: np.ndarray
    velocities: np.ndarray
    predicted: np.ndarray
    previous_modes: np.ndarray
    modes: np.ndarray
    release_codes: np.ndarray
    teleported: np.ndarray
    target: np.ndarray
    target_vel: np.ndarray
    check: np.ndarray
    depenetrate: np.ndarray
    vis_query: np.ndarray
    hold_error: np.ndarray | None = None
    let_go_unseen: np.ndarray | None = None
    cameras: tuple | None = None
    cover_t: np.ndarray | None = None
    proposal_log_weight: np.ndarray | None = None
    fused: np.ndarray | None = None
    jitter: np.ndarray | None = None
    out_of_reach: np.ndarray | None = None
    fall: Fall | None = None
    detections: np.ndarray | None = None
    set_moving: np.ndarray | None = None
    push_grip: np.ndarray | None = None
    placed_at_rest: np.ndarray | None = None

    @property
    def behind_cover(self) -> np.ndarray | None:
        """``(K, M)`` bool: the objects let go behind cover now (None: no ``cover_t``)."""
        return None if self.cover_t is None else np.isfinite(self.cover_t)


@dataclass(frozen=True)
class Settled:
    """The particles after physics and the Place / Release rules: ``poses (K, M, 7)``, ``velocities
    (K, M, 6)``, ``modes (K, M)``, ``on_top (K, M, M+1)``, ``is_in (K, M, M)``, ``supported (K, M)``,
    ``codes (K, M)`` (event codes of the whole update), ``tick_vel (M, 3)`` (perceived velocity
    over the reasoning period, m/s), ``holds (K, M, 6)`` (the hold records after the update,
    :mod:`actions.push`) and ``times (K, M)`` (s, when each event of ``codes`` happened, if before
    ``t``: a Pick's when the object started moving, a Push's its Pick's; NaN: at ``t``)."""

    poses: np.ndarray
    velocities: np.ndarray
    modes: np.ndarray
    on_top: np.ndarray
    is_in: np.ndarray
    supported: np.ndarray
    codes: np.ndarray
    tick_vel: np.ndarray
    holds: np.ndarray
    times: np.ndarray


@dataclass(frozen=True)
class Proposal:
    """One update's proposal (:meth:`~estimator.model.SceneModel.propose`): at time ``t`` (s), ``dt``
    (s) after the previous update, from ``frame`` (the newest), with the objects ``detected (M,)``
    since the previous update and ``perceived (M,)`` now, the ``cameras`` that took the frames (None:
    the scene's), the particles' ``move`` and the worlds' input ``batch``
    (:class:`~estimator.worlds.batch.BatchInput`, without what the pool's cache decides);
    ``moving_targets``: whether the divergence test carries a target teleported in motion on at its
    velocity (the moving teleports, :mod:`estimator.model.mechanisms.teleport`)."""

    t: float
    dt: float
    frame: object
    detected: np.ndarray
    perceived: np.ndarray
    cameras: tuple | None
    move: Move
    batch: object
    moving_targets: bool = False


@dataclass(frozen=True)
class Weighed:
    """One update after physics (:meth:`~estimator.model.SceneModel.weigh`): the particles ``settled``
    (:class:`Settled`), the ``evidence`` the terms read (:class:`~estimator.model.terms.Evidence`) and
    the new unnormalised ``log_weights (K,)`` (all zero after a recovery)."""

    settled: Settled
    evidence: object
    log_weights: np.ndarray
