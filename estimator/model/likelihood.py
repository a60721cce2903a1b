"""The terms of a particle's log-weight, one pure array function each, and the terms as objects.

K particles, M objects; positions in metres, quaternions ``(x, y, z, w)``, angles in radians. Every
function returns log-likelihoods (natural log, float64) and needs no estimator object.

* :func:`position_log_likelihood`: heavy-tailed (Gaussian plus uniform outliers) position likelihood;
* :func:`orientation_log_likelihood`: heavy-tailed orientation likelihood;
* :func:`detection_log_likelihood`: both, summed over the detected objects;
* :func:`negative_evidence_log_likelihood`: undetected objects a particle puts in plain view;
* :func:`mode_switch_log_prior`: the prior cost of the evidence-triggered mode switches;
* :func:`hand_reach_log_likelihood`: a held object seen out of reach of every tracked hand;
* :func:`exploded_log_likelihood`: zero weight for particles whose simulation exploded.

The terms of a particle's log-weight that call them, and the :class:`~estimator.model.terms.Evidence`
they read, are in :mod:`estimator.model.terms`.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

from actions.modes import ModePriors, is_held
from physics.transforms import quat_angle


def _with_outliers(log_density: np.ndarray, outlier_prob: float) -> np.ndarray:
    """``log((1 - eps) * exp(log_density) + eps)``: the mixture with a uniform outlier component of
    unit density (``eps = outlier_prob``; 0 leaves ``log_density`` as it is)."""
    if outlier_prob > 0:
        return np.logaddexp(math.log1p(-outlier_prob) + log_density, math.log(outlier_prob))
    return log_density


def position_log_likelihood(positions: np.ndarray, detected: np.ndarray, std: np.ndarray,
                            outlier_prob: float) -> np.ndarray:
    """Log-likelihood ``(K, N)`` float64 of N detected positions under each particle.

    Args:
        positions: ``(K, N, 3)`` the particles' positions of the N detected objects (m).
        detected: ``(N, 3)`` the detected positions (m).
        std: ``(N,)`` standard deviation of each detection, per axis (m; isotropic Gaussian).
        outlier_prob: weight ``eps`` in [0, 1) of a uniform outlier density of 1 per m^3: the
            likelihood is ``(1 - eps) N(x; mu, std^2 I) + eps`` (heavy tails: one wild detection
            does not kill every particle).
    """
    axes = np.repeat(np.asarray(std, dtype=float)[:, None], 3, axis=1)  # (N, 3): one std per axis
    z2 = np.sum(((positions - detected) / axes) ** 2, axis=-1)
    log_n = -0.5 * z2 - 0.5 * np.sum(np.log(2 * math.pi * axes**2), axis=-1)
    return _with_outliers(log_n, outlier_prob)


def velocity_log_likelihood(velocities: np.ndarray, seen: np.ndarray, std: np.ndarray, mask: np.ndarray,
                            outlier_prob: float) -> np.ndarray:
    """Log-likelihood ``(K,)`` float64 of perceived horizontal velocities under the particles'.

    Args:
        velocities: ``(K, M, 2)`` each particle's horizontal velocity of each object (m/s).
        seen: ``(M, 2)`` the perceived velocities (m/s).
        std: ``(M,)`` their standard deviation per axis (m/s).
        mask: ``(K, M)`` bool, the entries weighed (the others add nothing).
        outlier_prob: as :func:`position_log_likelihood`, a uniform outlier density of 1 per (m/s)^2.
    """
    return np.where(mask, _planar_log_density(velocities, seen, std, outlier_prob), 0.0).sum(axis=1)


def _planar_log_density(values: np.ndarray, seen: np.ndarray, std: np.ndarray, outlier_prob: float) -> np.ndarray:
    """``(K, M)``: the log-density of ``seen (M, 2)`` under isotropic normals about ``values (K, M, 2)``
    of standard deviation ``std (M,)`` per axis, mixed with the outlier floor (:func:`_with_outliers`)."""
    std = np.asarray(std, dtype=float)
    z2 = np.sum(((values - seen[None]) / std[None, :, None]) ** 2, axis=-1)
    return _with_outliers(-0.5 * z2 - np.log(2 * math.pi * std ** 2)[None, :], outlier_prob)


def acceleration_log_likelihood(accelerations: np.ndarray, seen: np.ndarray, std: np.ndarray, mask: np.ndarray,
                                temper: np.ndarray, outlier_prob: float) -> np.ndarray:
    """Log-likelihood ``(K,)`` float64 of perceived horizontal accelerations under the particles'.

    Args:
        accelerations: ``(K, M, 2)`` each particle's horizontal acceleration of each object (m/s^2).
        seen: ``(M, 2)`` the perceived accelerations (m/s^2).
        std: ``(M,)`` their standard deviation per axis (m/s^2).
        mask: ``(K, M)`` bool, the entries weighed.
        temper: ``(M,)`` in [0, 1], the power each object's likelihood is raised to (the share of its
            evidence that is new at this update).
        outlier_prob: as :func:`position_log_likelihood`, a uniform outlier density of 1 per (m/s^2)^2.

    The evidence compares the particles it applies to among themselves, and says nothing about the
    others (an object held in a particle, moved by an agent, has no deceleration of its own
    physics): for each object, a particle not weighed gets the log of the mean likelihood of those
    weighed, so that whether the object is free or held is left to the other terms.
    """
    accelerations = np.where(mask[..., None], accelerations, seen[None])  # what is not weighed may be NaN
    log_n = _planar_log_density(accelerations, seen, std, outlier_prob)
    n = mask.sum(axis=0)
    mean = logsumexp(log_n, axis=0, b=mask) - np.log(np.maximum(n, 1))  # log of the weighed ones' mean
    ll = np.where(mask, log_n, np.where(n > 0, mean, 0.0)[None, :])
    return (ll * np.asarray(temper, float)[None, :]).sum(axis=1)


def orientation_log_likelihood(orientations: np.ndarray, detected: np.ndarray, orientation_std: float,
                               outlier_prob: float) -> np.ndarray:
    """Log-likelihood ``(K, N)`` float64 of N detected orientations under each particle.

    Args:
        orientations: ``(K, N, 4)`` unit quaternions (x, y, z, w) of the particles' objects.
        detected: ``(N, 4)`` detected unit quaternions (x, y, z, w).
        orientation_std: standard deviation of the rotation angle between them (rad, > 0).
        outlier_prob: weight ``eps`` of the outlier component, as :func:`position_log_likelihood`.

    The log-density is ``-0.5 (angle / std)^2``, unnormalised (the constant is the same for every
    particle), mixed with the outlier floor: ``log((1 - eps) exp(-0.5 (angle / std)^2) + eps)``.
    """
    ang = quat_angle(orientations, detected)
    return _with_outliers(-0.5 * (ang / orientation_std) ** 2, outlier_prob)


def detection_log_likelihood(poses: np.ndarray, detected: np.ndarray, has_orientation: np.ndarray,
                             position_std: np.ndarray, orientation_std: float,
                             outlier_prob: float) -> np.ndarray:
    """Log-likelihood ``(K,)`` float64 of N detections: per object, the position term plus, for
    detections with an orientation (when ``orientation_std > 0``), the orientation term; summed.

    Args:
        poses: ``(K, N, 7)`` the particles' poses (position m, quaternion x, y, z, w) of the objects.
        detected: ``(N, 7)`` the detected poses (the quaternion is read only where ``has_orientation``).
        has_orientation: ``(N,)`` bool, detections that came with an orientation.
        position_std: ``(N,)`` m, see :func:`position_log_likelihood`.
        orientation_std: rad; 0 ignores orientations.
        outlier_prob: see :func:`position_log_likelihood`.
    """
    ll = position_log_likelihood(poses[..., :3], detected[:, :3], position_std, outlier_prob)
    if orientation_std > 0 and np.any(has_orientation):
        ll[:, has_orientation] += orientation_log_likelihood(
            poses[:, has_orientation, 3:], detected[has_orientation, 3:], orientation_std, outlier_prob)
    return ll.sum(axis=1)


def negative_evidence_log_likelihood(visible: np.ndarray, modes: np.ndarray, queried: np.ndarray,
                                     in_tracked_hand: np.ndarray, miss_prob: float,
                                     visibility_threshold: float, hand_occlusion: float | np.ndarray = 1.0,
                                     unseen_in_view: np.ndarray | None = None,
                                     perceived: np.ndarray | None = None,
                                     exempt: np.ndarray | None = None) -> np.ndarray:
    """Log-likelihood ``(K,)`` float64 of *not* detecting the ``queried`` objects.

    A particle pays ``log(miss_prob)`` for each queried object it puts in view of the camera (visible
    fraction at least ``visibility_threshold``), nothing for the others.

    An object HELD by a tracked hand may also be hidden by the hand or its person, which the particle
    worlds do not contain, and such a hiding lasts (a cup carried behind the back stays there): with
    probability ``hand_occlusion`` the person keeps it hidden, otherwise the camera misses it at each
    update with ``miss_prob``. After ``n`` updates in view without a detection the likelihood is
    ``h + (1 - h) miss_prob**n``; the update that makes it ``n + 1`` pays the ratio of the two. So a
    hand that stays in plain view while its object is not seen any more makes the particles that keep
    the object in it lose weight to those that let it go, but never more than a factor ``h`` in all.
    ``hand_occlusion = 1`` exempts held objects. The count starts when the object stops being
    ``perceived``: before, every particle holds it (no release happens while perceived) and pays the same.

    Args:
        visible: ``(K, M)`` float, fraction of each object's sample points the camera sees (0..1).
        modes: ``(K, M)`` int8, FREE / HELD.
        queried: ``(M,)`` bool, the known, dynamic, undetected objects whose visibility was computed.
        in_tracked_hand: ``(M,)`` bool, objects whose hand (when last detected) is tracked now.
        miss_prob: probability in (0, 1] that the camera misses an object in plain view.
        visibility_threshold: fraction of points in view for an object to count as visible.
        hand_occlusion: probability in [0, 1] that the person hides the object their hand holds, one
            for all or ``(M,)`` per object (0 for an object whose hand has not moved since it was
            seen: only the hand itself, already in ``visible``, can hide it then).
        unseen_in_view: ``(K, M)`` int, ``n`` before this update (None: zeros).
        perceived: ``(M,)`` bool, objects still perceived (None: none).
        exempt: ``(K, M)`` bool, entries that pay nothing (``Evidence.fell_unseen``; None: none).
    """
    if not np.any(queried):
        return np.zeros(len(visible))
    in_hand = is_held(modes) & np.asarray(in_tracked_hand, dtype=bool)[None, :]
    seen = visible >= visibility_threshold
    if exempt is not None:
        seen = seen & ~exempt
    out = math.log(miss_prob) * (seen & ~in_hand)[:, queried].sum(axis=1)
    if perceived is not None:
        in_hand = in_hand & ~np.asarray(perceived, dtype=bool)[None, :]
    h = np.broadcast_to(np.asarray(hand_occlusion, dtype=float), (len(queried),))[queried]
    if np.any(h < 1.0):
        held_seen = (seen & in_hand)[:, queried] & (h < 1.0)[None, :]
        if np.any(held_seen):
            n = np.zeros(held_seen.shape) if unseen_in_view is None else unseen_in_view[:, queried].astype(float)
            step = np.log(h + (1.0 - h) * miss_prob ** (n + 1)) - np.log(h + (1.0 - h) * miss_prob ** n)
            out = out + np.where(held_seen, step, 0.0).sum(axis=1)
    return out


def hidden_by_person(unseen_in_view: np.ndarray, hand_occlusion: float, miss_prob: float) -> np.ndarray:
    """The probability (float64, same shape as ``unseen_in_view``) that the person keeps a held
    object hidden, after ``n = unseen_in_view`` updates in view without a detection, under the
    model of :func:`negative_evidence_log_likelihood`: ``h / (h + (1 - h) miss_prob**n)`` (``h`` at
    ``n = 0``; 1 when ``hand_occlusion`` is 1). What a look at the hand can still hope to see is
    one minus this."""
    h = float(hand_occlusion)
    if h >= 1.0:
        return np.ones(np.shape(unseen_in_view))
    miss_n = float(miss_prob) ** np.asarray(unseen_in_view, dtype=float)
    return h / (h + (1.0 - h) * miss_n)


def mode_switch_log_prior(priors: ModePriors, previous: np.ndarray, new: np.ndarray,
                          perceived: np.ndarray) -> np.ndarray:
    """Log-prior ``(K,)`` float64 of the Pick / Place switches of an update, summed over objects
    (:meth:`ModePriors.log_prior_cost`: ``log(p)`` for a switch, ``log(1 - p)`` for an object that
    could have switched and did not, 0 for unperceived objects; -inf for a switch of prior 0).

    Args:
        priors: the switch probabilities.
        previous, new: ``(K, M)`` int8 modes before and after the update.
        perceived: ``(M,)`` bool, objects perceived in this update.
    """
    return priors.log_prior_cost(previous, new, np.asarray(perceived, dtype=bool)[None, :]).sum(axis=1)


def hand_reach_log_likelihood(modes: np.ndarray, out_of_reach: np.ndarray, held_out_of_reach: float) -> np.ndarray:
    """Log-likelihood ``(K,)`` float64 of where the tracked hands are, given who holds what: each
    particle pays ``log(held_out_of_reach)`` for every object it has HELD that is detected out of reach
    of every tracked hand (an agent moves what it holds with a hand; the prior is the probability
    that it is a hand nobody tracks). Free objects, and held objects within reach, pay nothing: the
    hands' positions say nothing about them.

    Args:
        modes: ``(K, M)`` int8, FREE / HELD after this update.
        out_of_reach: ``(M,)`` bool, objects detected in this update farther than the reach from every
            hand tracked in it (none when no hand is tracked).
        held_out_of_reach: probability in [0, 1] (0: such a particle gets zero weight).
    """
    n = np.sum(is_held(modes) & np.asarray(out_of_reach, dtype=bool)[None, :], axis=1)
    if held_out_of_reach > 0:
        return n * math.log(held_out_of_reach)
    return np.where(n > 0, -np.inf, 0.0)


def exploded_log_likelihood(finite: np.ndarray) -> np.ndarray:
    """``(K,)`` float64: 0 for particles whose simulation stayed finite, -inf (zero weight) for those
    that exploded (NaN or runaway velocities; ``finite (K,)`` bool from the pool)."""
    return np.where(finite, 0.0, -np.inf)
