"""Pure functions on log-weights: normalisation, effective sample size, resampling schemes.

All randomness comes from the ``numpy.random.Generator`` passed in.
"""
from __future__ import annotations

import numpy as np


def normalise_log_weights(log_w: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised weights ``(K,)`` and the log of the mean unnormalised weight.

    Non-finite log-weights (NaN, -inf) count as zero weight. If every weight is zero, returns
    uniform weights and ``-inf``: the caller decides how to recover.
    """
    log_w = np.asarray(log_w, dtype=float)
    finite = np.isfinite(log_w)
    if not np.any(finite):
        return np.full(len(log_w), 1.0 / len(log_w)), -np.inf
    m = np.max(log_w[finite])
    w = np.where(finite, np.exp(np.where(finite, log_w, m) - m), 0.0)
    s = w.sum()
    return w / s, float(m + np.log(s / len(log_w)))


def effective_sample_size(weights: np.ndarray) -> float:
    """Kish's effective sample size ``1 / sum(w**2)`` of normalised weights."""
    w = np.asarray(weights, dtype=float)
    return float(1.0 / np.sum(w * w))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Ancestor indices ``(n,)`` (default ``n = K``, the length of ``weights``) by systematic
    resampling: one uniform draw, ``n`` evenly spaced points.

    The cumulative sum is pinned to exactly 1 at its end so that round-off never yields index K.
    """
    w = np.asarray(weights, dtype=float)
    k = len(w)
    n = k if n is None else int(n)
    if n < 1:
        raise ValueError(f"systematic_resample needs n >= 1, got {n}")
    cum = np.cumsum(w)
    cum /= cum[-1]
    cum[-1] = 1.0
    points = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cum, points, side="right").clip(0, k - 1)


def multinomial_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Ancestor indices ``(K,)`` drawn independently with probabilities ``weights``."""
    w = np.asarray(weights, dtype=float)
    return rng.choice(len(w), size=len(w), p=w / w.sum())


def keep_survivors_in_place(ancestors: np.ndarray) -> np.ndarray:
    """The same multiset of ancestor indices ``(n,)``, permuted so that every ancestor ``a < n`` that
    survives is copied into its own slot (``out[a] == a``); the other copies fill the remaining
    slots in increasing order of ancestor. A particle world keeps what it holds when its slot keeps
    its particle, so fewer worlds must load a new state (and wake). Deterministic; the slots' order
    carries no meaning for the filter. (``n`` may differ from the number of particles resampled, when
    the filter changes its particle count.)"""
    anc = np.asarray(ancestors)
    n = len(anc)
    out = np.full(n, -1, dtype=anc.dtype)
    survivors = np.unique(anc[anc < n])
    out[survivors] = survivors
    counts = np.bincount(anc, minlength=n)
    counts[survivors] -= 1
    extra = np.repeat(np.arange(len(counts)), counts)  # one entry per copy not yet placed, sorted
    out[out < 0] = extra
    return out


def split_ancestors(weights: np.ndarray, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Grow K particles to ``n > K`` without resampling: ancestor indices ``(n,)`` and the new
    normalised weights ``(n,)``. The first K entries are the particles themselves (``out[i] == i``);
    the ``n - K`` others are copies drawn by systematic resampling of ``weights (K,)`` (normalised),
    in increasing order of ancestor. Each particle's weight is shared equally among it and its
    copies, so every weighted average over the particles is the same before and after: nothing is
    lost and no resampling noise is added (splitting, as against resampling to ``n``)."""
    w = np.asarray(weights, dtype=float)
    k = len(w)
    if not n > k:
        raise ValueError(f"split_ancestors grows K: need n > {k}, got {n}")
    extra = np.sort(systematic_resample(w, rng, n - k))
    anc = np.concatenate([np.arange(k), extra])
    counts = np.bincount(anc, minlength=k)
    return anc, w[anc] / counts[anc]
