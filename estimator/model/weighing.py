"""How a particle is weighed: the evidence of an update and the sum of the log-weight terms.

Functions of the scene model (:class:`~estimator.model.SceneModel`, passed as ``model``): K particles,
M objects. The terms themselves are in :mod:`estimator.model.likelihood`; :func:`log_weight_terms` lists
those a model sums (a new term is one entry there), :func:`evidence` gathers what they read.
"""
from __future__ import annotations

import numpy as np

from actions.modes import is_free, is_held
from physics.visibility import sphere_occlusion

from ..observations import Frame
from ..resampling import normalise_log_weights
from ..worlds.pool import BatchOutput
from .likelihood import exploded_log_likelihood
from .step import Move, Settled
from .terms import (
    DetectionTerm,
    Evidence,
    HandReachTerm,
    LogWeightTerm,
    ModeSwitchTerm,
    NegativeEvidenceTerm,
    ProposalTerm,
    add_terms,
)

SURPRISE = 4.0
"""An object whose perceived velocity has been, on average (:meth:`~estimator.model.mechanisms.velocity.VelocityEvidence.after_weighing`), more
than two of its standard deviations away from what the particles predicted (squared, per axis, over
two axes: 4) has its frictions' kernel widened to ``NoiseConfig.param_widen`` at the next
resampling: every particle is wrong about how it slows down."""


def diverged_by(move: Move, out: BatchOutput) -> np.ndarray:
    """``(K, M)`` float: the divergence (m) at which physics overrode each free, checked object
    (the pool switched it to HELD and put it on its perception, Algorithm 1), NaN for the others
    (``Evidence.diverged``)."""
    over = move.check & is_free(move.modes) & is_held(out.modes)
    return np.where(over, out.max_divergence, np.nan)


def log_weight_terms(model) -> tuple[LogWeightTerm, ...]:
    """The terms a particle's log-weight is the sum of, in the order they are added: those of every
    model (the detections, negative evidence, the mode switches' prior, the hands' reach, the
    proposal's importance weights), then each mechanism's own (:meth:`Mechanism.terms
    <estimator.model.mechanisms.base.Mechanism.terms>`, in the order of the list). A new term of
    every model goes here; a mechanism's, in its module."""
    nz, cfg = model.config.noise, model.config
    core = (DetectionTerm(nz.position_std, nz.orientation_std, nz.outlier_prob),
            NegativeEvidenceTerm(nz.miss_prob, cfg.visibility_threshold, nz.hand_occlusion),
            ModeSwitchTerm(cfg.priors), HandReachTerm(cfg.priors.held_out_of_reach), ProposalTerm())
    return core + tuple(term for mechanism in model.mechanisms for term in mechanism.terms())


def evidence(model, move: Move, settled: Settled, out: BatchOutput, frame: Frame, detected: np.ndarray,
             perceived: np.ndarray, unseen_in_view: np.ndarray) -> Evidence:
    """What the log-weight terms read for this update (``unseen_in_view (K, M)``: the particles'
    counts before it, see :class:`~estimator.state.ParticleState`)."""
    mem = model.memory
    carried = mem.hand_travel() > model.config.priors.carry_distance
    # an object its hand has not moved since it was last detected there is not hidden by that hand
    following = mem.following_hand(frame)
    seen_in_hand = following & ~carried
    visible = behind_hands(model, out.visible, settled.poses, out.aabbs, frame, move.cameras,
                                move.vis_query & ~seen_in_hand)
    return Evidence(poses=settled.poses, predicted=move.predicted, previous_modes=move.previous_modes,
                    modes=settled.modes, detected=detected & model.dynamic, teleported=move.teleported,
                    perceived=perceived, detected_poses=mem.last_pose if move.detections is None else move.detections,
                    has_orientation=mem.last_has_orientation, detection_std=mem.last_std,
                    visible=visible, queried=move.vis_query,
                    in_tracked_hand=following, finite=out.finite,
                    unseen_in_view=unseen_in_view,
                    fell_unseen=None if move.let_go_unseen is None else is_free(settled.modes)
                    & (frame.t - move.let_go_unseen < model.config.reasoner.t_perceived - 1e-9),
                    proposal_log_weight=move.proposal_log_weight, fused=move.fused,
                    out_of_reach=move.out_of_reach, diverged=diverged_by(move, out),
                    fell=None if move.fall is None else move.fall.mask,
                    carried=carried)


def behind_hands(model, visible: np.ndarray, poses: np.ndarray, aabbs: np.ndarray, frame: Frame,
                 cameras: tuple | None, queried: np.ndarray) -> np.ndarray:
    """``visible (K, M)`` with what the tracked hands of ``frame`` hide taken out: each queried
    object ``queried (M,)``, a ball of its box's mean half extent (``aabbs (K, M, 2, 3)``) at its
    position in ``poses (K, M, 7)``, keeps ``1 - share`` of its visible fraction, ``share`` being
    the part of its disk a hand (``NoiseConfig.hand_radius``) covers from the camera that sees
    the most of it (:func:`~physics.visibility.sphere_occlusion`; ``cameras``: those of the
    update, None: the scene's). The worlds hold no hands. (The caller leaves out an object whose
    hand has not moved since it was last detected in it: it was seen there, so its hand does
    not hide it.)"""
    r = model.config.noise.hand_radius
    if not frame.hands or r <= 0 or not np.any(queried):
        return visible
    cams = [model.scene.camera] if cameras is None else list(cameras)
    cams = [c for c in cams if c is not None]
    if not cams:
        return visible
    idx = np.flatnonzero(queried)
    hands = np.array([np.asarray(h, dtype=float) for h in frame.hands.values()])
    radii = 0.5 * np.mean(aabbs[:, idx, 1] - aabbs[:, idx, 0], axis=-1)
    shares = [sphere_occlusion(np.asarray(c.position, float), poses[:, idx, :3], radii, hands, r) for c in cams]
    out = visible.copy()
    out[:, idx] = visible[:, idx] * (1.0 - np.min(shares, axis=0))
    return out


def log_weight(model, previous: np.ndarray, ev: Evidence) -> np.ndarray:
    """New log-weights ``(K,)``: ``previous (K,)`` plus every term of :attr:`terms` (one particle
    has nothing to be weighed against: no terms), and -inf for exploded particles."""
    logw = add_terms(previous, model.terms, ev) if model.K > 1 else previous.copy()
    logw = logw + exploded_log_likelihood(ev.finite)
    for mechanism in model.mechanisms:
        mechanism.after_weighing(ev, logw)
    return logw


def mean_innovation(logw: np.ndarray, mask: np.ndarray, predicted: np.ndarray, seen: np.ndarray,
                    std: np.ndarray) -> np.ndarray:
    """``(M,)``: half the squared distance, in standard deviations ``std (M,)`` per axis, between what
    was perceived, ``seen (M, 2)``, and the particles' prediction ``predicted (K, M, 2)`` averaged
    under the weights ``logw (K,)`` over the particles ``mask (K, M)`` (about 1 when calibrated); NaN
    for objects no weighted particle predicts."""
    out = np.full(len(seen), np.nan)
    if len(logw) < 2 or not np.any(np.isfinite(logw)):
        return out
    w, _ = normalise_log_weights(logw)
    for m in np.flatnonzero(mask.any(axis=0)).tolist():
        wm = w * mask[:, m]
        if wm.sum() <= 0:
            continue
        d = (seen[m] - (wm[:, None] * predicted[:, m]).sum(axis=0) / wm.sum()) / std[m]
        out[m] = float(d @ d) / 2.0
    return out
