"""The terms of a particle's log-weight as objects, and the evidence of an update they read.

The scene model (:class:`~estimator.model.SceneModel`) weighs a particle with a tuple of *terms*:
callables ``term(evidence) -> (K,)`` that read what they need from one :class:`Evidence` (the
per-update arrays) and call one of the pure functions of :mod:`estimator.model.likelihood`. A new
term (a search look, a tracker pseudo-measurement) is a new function there, a term object here
calling it, and one entry in the tuple :func:`~estimator.model.weighing.log_weight_terms` returns.
A mechanism's own term lives in the mechanism's module (:meth:`Mechanism.terms
<estimator.model.mechanisms.base.Mechanism.terms>`) and reads what that mechanism kept of the
update (the velocity and deceleration evidence do so), not a new field of :class:`Evidence`. Terms are added one after the other to the previous
log-weights, in the order of that tuple; exploded particles get -inf whatever the terms say.
K particles, M objects.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from actions.modes import ModePriors, is_free, is_held

from .likelihood import (
    detection_log_likelihood,
    hand_reach_log_likelihood,
    mode_switch_log_prior,
    negative_evidence_log_likelihood,
)


@dataclass(frozen=True)
class Evidence:
    """What the terms of one update read (K particles, M objects).

    * ``poses (K, M, 7)``: the particles after physics; ``predicted (K, M, 7)``: before the update's
      teleports (a teleported object is scored where the particle expected it, not where it was put).
    * ``previous_modes``, ``modes`` ``(K, M)`` int8: modes at the previous update and now.
    * ``detected (M,)``: dynamic objects detected since the previous update; ``teleported (M,)``;
      ``perceived (M,)``: dynamic objects seen within ``t_perceived``.
    * ``detected_poses (M, 7)``: latest detection per object, carried to the update's time when it
      was detected in an earlier frame, by its tracked hand or at its velocity (m; quaternion x, y, z, w,
      :meth:`~estimator.model.perception_memory.PerceptionMemory.detections_now`);
      ``has_orientation (M,)``; ``detection_std (M,)`` m, the detector's position std (NaN: unknown).
    * ``visible (K, M)``: visible fractions from the pool (0 where not queried); ``queried (M,)``:
      objects whose visibility was computed; ``in_tracked_hand (M,)``: objects whose hand is tracked.
    * ``finite (K,)``: particles whose simulation stayed finite.
    * ``unseen_in_view (K, M)`` int: the particles' counts before this update (see
      :class:`~estimator.state.ParticleState`).
    * ``fell_unseen (K, M)`` bool: free objects the particle let go less than ``t_perceived`` ago
      when they stopped being perceived: in truth they fell in the ``t_perceived`` before, unseen,
      and the particle's late fall in view is no evidence against it (None: none).
    * ``proposal_log_weight (K,)``: the weight factor of this update's importance moves (objects
      let go behind cover, :func:`~estimator.model.hidden.release_behind_cover`; None: none).
    * ``fused (K, M)`` bool: resting objects moved towards their detection before physics
      (:func:`~estimator.model.fusion.ensemble_kalman_step`), scored, as teleported ones, where the
      particle expected them (None: none).
    * ``out_of_reach (M,)`` bool: objects detected in this update out of reach of every tracked
      hand (None: no hand tracked, or hands not followed).
    * ``diverged (K, M)`` float: for free, checked objects that physics let diverge from their
      detection by more than ``d_sim_perc`` during the update (Algorithm 1: the world then put
      them on the perception and held them there), the divergence at that moment (m); NaN elsewhere
      (None: none). They are scored at that distance from their detection, not where they were put:
      the override is a correction, not evidence that the particle was right.
    * ``carried (M,)`` bool: objects whose tracked hand has moved more than ``carry_distance`` since
      they were last seen (the person may hide what they carry: ``NoiseConfig.hand_occlusion``
      applies to them only; None: to every held object).
    * ``fell (M,)`` bool: objects seen rolling along at the previous update and falling off their
      support in this one (:class:`~estimator.model.step.Fall`); in the particles where they are free after
      the update (free before, or let go by the Release rule) they are scored on their horizontal
      position only. A particle's prediction carries the object on at its velocity, which knows
      nothing of when the fall began: up to ``g dt**2 / 2`` (4.9 cm at 10 Hz) of height no particle
      can explain better than another, and weighed at a detection's few millimetres it would leave
      one survivor. A copy still held is weighed on its height: on a lagging (filtered) stream the
      Release rule may not let it go, and held in the air it must not be spared (None: none).
    """

    poses: np.ndarray
    predicted: np.ndarray
    previous_modes: np.ndarray
    modes: np.ndarray
    detected: np.ndarray
    teleported: np.ndarray
    perceived: np.ndarray
    detected_poses: np.ndarray
    has_orientation: np.ndarray
    detection_std: np.ndarray
    visible: np.ndarray
    queried: np.ndarray
    in_tracked_hand: np.ndarray
    finite: np.ndarray
    unseen_in_view: np.ndarray
    fell_unseen: np.ndarray | None = None
    proposal_log_weight: np.ndarray | None = None
    fused: np.ndarray | None = None
    out_of_reach: np.ndarray | None = None
    diverged: np.ndarray | None = None
    fell: np.ndarray | None = None
    carried: np.ndarray | None = None


LogWeightTerm = Callable[[Evidence], np.ndarray]
"""A term of the log-weight: ``term(evidence) -> (K,)`` float64."""


@dataclass(frozen=True)
class DetectionTerm:
    """The detections of this update (:func:`detection_log_likelihood`). A detection without a std
    uses ``max(default_std, 1e-3)`` m. Objects teleported or fused before physics are scored where
    the particle expected them (``Evidence.predicted``); objects that physics let diverge
    (``Evidence.diverged``) at their divergence from the detection, with the orientation the
    particle expected (the isotropic position term depends on that distance only); objects that
    fell off their support in the update (``Evidence.fell``), and are free after it, on their
    horizontal position only."""

    default_std: float
    orientation_std: float
    outlier_prob: float

    def __call__(self, ev: Evidence) -> np.ndarray:
        idx = np.flatnonzero(ev.detected)
        if len(idx) == 0:
            return np.zeros(len(ev.poses))
        expected = np.broadcast_to(ev.teleported[idx][None, :], (len(ev.poses), len(idx)))
        if ev.fused is not None:
            expected = expected | ev.fused[:, idx]
        src = np.where(expected[..., None], ev.predicted[:, idx], ev.poses[:, idx])  # a new array
        if ev.diverged is not None:
            d = ev.diverged[:, idx]
            over = np.isfinite(d)
            if np.any(over):  # a point at the divergence from the detection, along x
                at = np.broadcast_to(ev.detected_poses[idx, :3], d.shape + (3,)).copy()
                at[..., 0] += np.where(over, d, 0.0)
                src[..., :3] = np.where(over[..., None], at, src[..., :3])
                src[..., 3:] = np.where(over[..., None], ev.predicted[:, idx, 3:], src[..., 3:])
        if ev.fell is not None and np.any(ev.fell[idx]):  # the height of a free one: the detection's own
            flat = ev.fell[idx][None, :] & is_free(ev.modes[:, idx])
            src[..., 2] = np.where(flat, ev.detected_poses[idx, 2][None, :], src[..., 2])
        std = ev.detection_std[idx]
        std = np.where(np.isfinite(std), std, max(self.default_std, 1e-3))
        return detection_log_likelihood(src, ev.detected_poses[idx], ev.has_orientation[idx], std,
                                        self.orientation_std, self.outlier_prob)


@dataclass(frozen=True)
class NegativeEvidenceTerm:
    """Undetected objects in view (:func:`negative_evidence_log_likelihood`); ``hand_occlusion``
    applies to the objects ``Evidence.carried`` says their hand carries (to every held one when it
    is None), 0 to the others (1, paper mode's exemption, to all)."""

    miss_prob: float
    visibility_threshold: float
    hand_occlusion: float = 1.0

    def __call__(self, ev: Evidence) -> np.ndarray:
        h = self.hand_occlusion
        if ev.carried is not None and h < 1.0:
            h = np.where(np.asarray(ev.carried, dtype=bool), h, 0.0)
        return negative_evidence_log_likelihood(ev.visible, ev.modes, ev.queried, ev.in_tracked_hand,
                                                self.miss_prob, self.visibility_threshold, h,
                                                ev.unseen_in_view, ev.perceived, ev.fell_unseen)


@dataclass(frozen=True)
class ModeSwitchTerm:
    """The prior cost of Pick / Place (:func:`mode_switch_log_prior`)."""

    priors: ModePriors

    def __call__(self, ev: Evidence) -> np.ndarray:
        return mode_switch_log_prior(self.priors, ev.previous_modes, ev.modes, ev.perceived)


@dataclass(frozen=True)
class HandReachTerm:
    """Held objects seen out of reach of the tracked hands (:func:`hand_reach_log_likelihood`)."""

    held_out_of_reach: float

    def __call__(self, ev: Evidence) -> np.ndarray:
        if ev.out_of_reach is None:
            return np.zeros(len(ev.poses))
        return hand_reach_log_likelihood(ev.modes, ev.out_of_reach, self.held_out_of_reach)


@dataclass(frozen=True)
class ProposalTerm:
    """The weight factor of the scene model's importance moves (``Evidence.proposal_log_weight``)."""

    def __call__(self, ev: Evidence) -> np.ndarray:
        if ev.proposal_log_weight is None:
            return np.zeros(len(ev.poses))
        return np.asarray(ev.proposal_log_weight, dtype=float)


def add_terms(log_weights: np.ndarray, terms: tuple[LogWeightTerm, ...], ev: Evidence) -> np.ndarray:
    """``log_weights (K,)`` plus every term, added one after the other in the order given."""
    out = log_weights.copy()
    for term in terms:
        out += term(ev)
    return out


def held_unseen_in_view(ev: "Evidence", visibility_threshold: float) -> np.ndarray:
    """The counts ``(K, M)`` int32 after this update: ``ev.unseen_in_view`` plus one where a held,
    unperceived object in a tracked hand was queried and in view; zero for objects detected in this
    update or not held (see :func:`negative_evidence_log_likelihood`)."""
    n = ev.unseen_in_view.astype(np.int32, copy=True)
    in_hand = is_held(ev.modes) & (np.asarray(ev.in_tracked_hand, dtype=bool) & ~ev.perceived)[None, :]
    counted = in_hand & ev.queried[None, :] & (ev.visible >= visibility_threshold)
    n[counted] += 1
    n[is_free(ev.modes) | ev.detected[None, :]] = 0
    return n
