"""Detections fused into the particles of objects at rest: an ensemble Kalman step.

A perceived object resting on its support is, for a particle filter, a static parameter: physics
does not move it, so the particles keep the positions they were given when it was first perceived
(the detection plus ``position_std`` noise), and weighting and resampling can only pick among them.
The cloud then settles on whichever few particles were drawn closest, and a systematic drift of
its worlds (contacts settling a centimetre) is never undone: the paper's deterministic reasoner,
which puts the object at the detection, ends closer to the truth.

Each update, the horizontal position of such an object in each particle takes a stochastic
ensemble Kalman step towards the latest detection: with the particles' weighted variance ``P`` per
axis (plus a floor) and the detection's variance ``R``, the gain is ``G = P / (P + R)`` and particle
k moves to ``x_k + G (d + e_k - x_k)``, ``e_k ~ N(0, R)`` (perturbed observations, so that the
spread after the step is the Kalman posterior's). Repeated, the cloud converges to the mean of the
detections with the variance a Kalman filter of a static position gives. The vertical is left to
physics (trackers' heights are biased; the support decides). Steps smaller than ``min_step`` are
not taken, so that converged objects stay asleep in their worlds.

Arrays: K particles, N objects; metres.
"""
from __future__ import annotations

import numpy as np


def weighted_axis_variance(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted variance ``(N, D)`` of ``x (K, N, D)`` over the particles, ``weights (K,)``
    normalised."""
    mean = np.einsum("k,knd->nd", weights, x)
    return np.einsum("k,knd->nd", weights, (x - mean) ** 2)


def ensemble_kalman_step(x: np.ndarray, weights: np.ndarray, detected: np.ndarray, std: np.ndarray,
                         mask: np.ndarray, rng: np.random.Generator, floor_std: float = 0.0,
                         min_step: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One stochastic ensemble Kalman step of ``x (K, N, D)`` towards ``detected (N, D)``.

    Args:
        x: particle positions (m), not modified.
        weights: ``(K,)`` normalised weights (the prior variance is the weighted one).
        detected: the detections (m).
        std: ``(N,)`` standard deviation of each detection per axis (m, > 0).
        mask: ``(K, N)`` bool, the entries that take the step (the others keep their position; the
            variance is that of the masked entries' objects over all particles).
        rng: source of the perturbed observations (drawn for every entry, masked or not, so the
            stream does not depend on the mask).
        floor_std: added as ``floor_std**2`` to the prior variance (m): the gain never drops to 0.
        min_step: entries whose step is shorter than this (m) keep their position.

    Returns:
        ``(new x (K, N, D), moved (K, N) bool)``.
    """
    K, N, D = x.shape
    if detected.shape != (N, D) or std.shape != (N,) or mask.shape != (K, N) or weights.shape != (K,):
        raise ValueError(f"ensemble_kalman_step: x {x.shape}, detected {detected.shape}, std {std.shape}, "
                         f"mask {mask.shape}, weights {weights.shape} do not agree")
    r = (np.asarray(std, dtype=float) ** 2)[:, None]  # (N, 1)
    p = weighted_axis_variance(x, weights) + floor_std ** 2  # (N, D)
    gain = p / (p + r)
    e = rng.normal(0.0, 1.0, x.shape) * np.sqrt(r)[None]
    step = gain[None] * (detected[None] + e - x)
    moved = mask & (np.linalg.norm(step, axis=-1) >= min_step)
    out = np.where(moved[..., None], x + step, x)
    return out, moved


def shift_inconsistent(x: np.ndarray, weights: np.ndarray, target: np.ndarray, target_se: np.ndarray,
                       mask: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Clouds that the evidence rejects, moved whole to ``target``.

    An ensemble Kalman step (:func:`ensemble_kalman_step`) trusts the cloud's own spread: a narrow
    cloud away from where the object is seen hardly moves (its gain is its variance's, or the
    floor's, against the detection noise) and can stay there for good. Narrow clouds are common: an
    object put at one detection in every particle (a held object let go where it was seen), or a
    cloud thinned by resampling to a few ancestors. The test is the Kalman filter's innovation
    test: the gap between the cloud's weighted mean and ``target`` (the average of the object's
    detections while still, whose standard error is ``target_se``), against the standard deviation
    of that gap, ``sqrt(u' P u + target_se^2)`` with ``P`` the cloud's weighted covariance and ``u``
    the gap's direction. A gap over ``z`` of those says that the cloud is not where the object is;
    the cloud then moves whole, every particle by the same shift (its shape, the relative
    uncertainty of its particles, is kept, and no particle is weighed against another for it).

    Args:
        x: ``(K, N, D)`` particle positions (m), not modified.
        weights: ``(K,)`` normalised weights.
        target: ``(N, D)`` where each cloud goes (m): the average of its still detections.
        target_se: ``(N,)`` standard error of each target per axis (m).
        mask: ``(K, N)`` bool, the entries that may move.
        z: the gap, in standard deviations, over which a cloud moves.

    Returns:
        ``(new x (K, N, D), moved (K, N) bool)``: the masked entries of the clouds moved.
    """
    K, N, D = x.shape
    if target.shape != (N, D) or target_se.shape != (N,) or mask.shape != (K, N) or weights.shape != (K,):
        raise ValueError(f"shift_inconsistent: x {x.shape}, target {target.shape}, target_se {target_se.shape}, "
                         f"mask {mask.shape}, weights {weights.shape} do not agree")
    mean = np.einsum("k,knd->nd", weights, x)
    gap = target - mean  # (N, D)
    dist = np.linalg.norm(gap, axis=1)
    u = gap / np.where(dist > 0.0, dist, 1.0)[:, None]
    spread = np.einsum("k,kn->n", weights, np.einsum("knd,nd->kn", x - mean, u) ** 2)  # u' P u
    rejected = dist > z * np.sqrt(spread + np.square(target_se))  # (N,)
    moved = mask & rejected[None, :]
    out = np.where(moved[..., None], x + gap[None], x)
    return out, moved
