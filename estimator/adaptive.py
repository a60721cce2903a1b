"""How many particles the belief needs: KLD-sampling (Fox, 2003) over each object's binned marginal.

Pure functions on arrays (see :class:`~estimator.config.AdaptiveConfig` for the bound and its
assumptions); the filter (:class:`~estimator.filter.SceneEstimator`) resamples to the count they
give (under the compute budget's cap, :func:`~estimator.config.budget_cap`, when there is one).
The minimum they are clipped to comes from how well a cloud's regions can be estimated from K
samples (:func:`region_coverage`, :func:`coverage_min_particles`).
"""
from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
from scipy.special import fdtr

from .belief import chi2_quantile
from .config import AdaptiveConfig

__all__ = ["kld_bound", "occupied_bins", "particles_needed", "region_coverage", "coverage_min_particles"]


def kld_bound(k: int | np.ndarray, epsilon: float, delta: float) -> np.ndarray:
    """Samples needed so that, with probability ``1 - delta``, the Kullback-Leibler divergence
    between a distribution over ``k`` bins with support and its maximum-likelihood estimate from the
    samples stays under ``epsilon``: the chi-square quantile ``chi2(k - 1, 1 - delta) / (2 epsilon)``
    in the Wilson-Hilferty approximation. ``k`` an int or an array of ints (>= 0); 0 for ``k <= 1``
    (one bin needs no sample to be estimated). Returns float, same shape as ``k``."""
    k = np.asarray(k, dtype=float)
    z = NormalDist().inv_cdf(1.0 - delta)
    d = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * d)
    n = d / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(k > 1, n, 0.0)


def region_coverage(k: int | np.ndarray, level: float = 0.9, dim: int = 3) -> np.ndarray:
    """How often, on average, a new draw from a ``dim``-dimensional Gaussian falls in the ``level``
    region fitted to ``k`` samples of it (mean and covariance estimated from them, radius the
    chi-square quantile as though they were exact). Hotelling: with ``x`` the new draw and ``m, S`` the
    samples' mean and (unbiased) covariance, ``(x - m)' S^-1 (x - m) * k (k - dim) / ((k + 1) (k - 1)
    dim)`` is F(dim, k - dim) distributed. ``k`` an int or an array of ints (> ``dim``); returns float,
    same shape, under ``level`` and rising to it as ``k`` grows."""
    k = np.asarray(k, dtype=float)
    if np.any(k <= dim) or not 0.0 < level < 1.0:
        raise ValueError(f"region_coverage: k must exceed dim ({dim}) and level be in (0, 1), got {k!r}, {level!r}")
    radius = chi2_quantile(level, dim)
    return fdtr(dim, k - dim, radius * k * (k - dim) / ((k + 1.0) * (k - 1.0) * dim))


def coverage_min_particles(levels=(0.5, 0.9), shortfall: float = 0.01, dim: int = 3) -> int:
    """The least K whose fitted regions at every one of ``levels`` cover, on average, at least their
    level less ``shortfall`` (:func:`region_coverage`): the fewest particles from which a cloud's
    regions can be estimated to that tolerance. The defaults are the regions the estimator's priors
    are calibrated for (``fit-priors --regions``) and one percentage point. Searched up to 10^5."""
    if not all(0.0 < shortfall < level < 1.0 for level in levels):
        raise ValueError(f"coverage_min_particles: need 0 < shortfall < level < 1, got {shortfall!r}, {levels!r}")
    k = np.arange(dim + 1, 10**5)
    ok = np.all([region_coverage(k, level, dim) >= level - shortfall for level in levels], axis=0)
    if not ok[-1]:
        raise ValueError(f"coverage_min_particles: no K under 10^5 covers within {shortfall!r}")
    return int(k[np.argmax(ok)])  # coverage rises with K: the first that holds


def occupied_bins(positions: np.ndarray, modes: np.ndarray, weights: np.ndarray, bin_size: float,
                  min_mass: float) -> int:
    """Bins of one object that hold at least ``min_mass`` of the weight.

    ``positions (K, 3)`` m, ``modes (K,)`` int, ``weights (K,)`` normalised. Bins are cubes of
    ``bin_size`` m centred on the weighted mean position, one set per mode; non-finite positions are
    left out."""
    ok = np.all(np.isfinite(positions), axis=1) & (weights > 0)
    if not np.any(ok):
        return 0
    p, w, md = positions[ok], weights[ok], np.asarray(modes)[ok]
    mean = np.sum(p * w[:, None], axis=0) / np.sum(w)
    cells = np.floor((p - mean) / bin_size + 0.5).astype(np.int64)
    keys = np.concatenate([cells, md[:, None].astype(np.int64)], axis=1)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    mass = np.bincount(inverse.ravel(), weights=w)
    return int(np.count_nonzero(mass >= min_mass))


def particles_needed(poses: np.ndarray, modes: np.ndarray, weights: np.ndarray, objects: np.ndarray,
                     config: AdaptiveConfig) -> tuple[int, np.ndarray]:
    """The particle count the belief needs, and the bins counted per object ``(M,)`` (0 for objects
    not in ``objects``).

    ``poses (K, M, 7)``, ``modes (K, M)``, ``weights (K,)`` normalised, ``objects (M,)`` bool: those
    binned (the known dynamic ones). The largest :func:`kld_bound` over the objects, rounded up,
    clipped to ``[config.min_particles, config.max_particles]``. A bin counts when it holds at least
    half a particle's share of the weight (``1 / (2 K)``)."""
    poses = np.asarray(poses, dtype=float)
    K, M = poses.shape[:2]
    if modes.shape != (K, M) or weights.shape != (K,) or objects.shape != (M,):
        raise ValueError(f"particles_needed: poses {poses.shape}, modes {modes.shape}, weights {weights.shape}, "
                         f"objects {objects.shape} do not agree")
    bins = np.zeros(M, dtype=int)
    for m in np.flatnonzero(objects).tolist():
        bins[m] = occupied_bins(poses[:, m, :3], modes[:, m], weights, config.bin_size, 0.5 / K)
    n = float(np.max(kld_bound(bins, config.epsilon, config.delta), initial=0.0))
    return int(min(max(math.ceil(n), config.min_particles), config.max_particles)), bins
