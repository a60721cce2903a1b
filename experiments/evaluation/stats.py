"""Statistics across seeds: bootstrap confidence intervals (scipy) and the paired Wilcoxon signed-rank test.

Randomness only from a passed :class:`numpy.random.Generator`; :func:`group_rng` derives a
reproducible one from a group's name, so a summary does not depend on the order of its rows.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Interval:
    """A point estimate with a confidence interval ``[low, high]`` from ``n`` finite values."""

    estimate: float
    low: float
    high: float
    n: int


def bootstrap_ci(values, rng: np.random.Generator, *, n_resamples: int = 2000, confidence: float = 0.95,
                 statistic=np.mean) -> Interval:
    """Percentile-bootstrap interval of ``statistic`` of ``values`` (NaNs are dropped), by
    :func:`scipy.stats.bootstrap`.

    Args:
        values: 1-D sample (e.g. one metric over seeds).
        rng: source of the resampling indices.
        n_resamples: bootstrap resamples.
        confidence: coverage of the interval (0.95: the 2.5 and 97.5 percentiles).
        statistic: function of a 1-D array along ``axis=-1`` (``np.mean``, ``np.median``).

    Returns an :class:`Interval`; with fewer than two values the interval is NaN (nothing to
    resample), and with no values everything is NaN.
    """
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    est = float(statistic(v))
    if n < 2:
        return Interval(est, math.nan, math.nan, n)
    from scipy.stats import bootstrap  # scipy.stats costs a second to import: only where it is used

    res = bootstrap((v,), statistic, n_resamples=n_resamples, confidence_level=confidence, method="percentile",
                    vectorized=True, axis=-1, rng=rng)
    return Interval(est, float(res.confidence_interval.low), float(res.confidence_interval.high), n)


@dataclass(frozen=True)
class PairedTest:
    """Wilcoxon signed-rank test of paired samples a, b: ``n`` pairs with both values finite,
    ``n_nonzero`` of them with a non-zero difference, ``median_diff`` = median of (a - b), the
    test ``statistic`` and two-sided ``p_value`` (1.0 when every difference is zero, NaN with no
    pairs)."""

    n: int
    n_nonzero: int
    median_diff: float
    statistic: float
    p_value: float


def paired_wilcoxon(a, b, decimals: int = 12) -> PairedTest:
    """Two-sided Wilcoxon signed-rank test of ``a`` against ``b`` (1-D, paired by position, e.g. by
    seed). Pairs with a NaN are dropped; differences are rounded to ``decimals`` so that round-off
    does not break ties; zero differences are discarded (scipy's ``zero_method="wilcox"``)."""
    a = np.asarray(a, float).ravel()
    b = np.asarray(b, float).ravel()
    if a.shape != b.shape:
        raise ValueError(f"paired samples differ in length: {a.shape} vs {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    d = np.round(a[ok] - b[ok], decimals)
    n = int(d.size)
    if n == 0:
        return PairedTest(0, 0, math.nan, math.nan, math.nan)
    nz = int(np.count_nonzero(d))
    med = float(np.median(d))
    if nz == 0:
        return PairedTest(n, 0, med, 0.0, 1.0)
    from scipy.stats import wilcoxon

    res = wilcoxon(d, zero_method="wilcox", alternative="two-sided")
    return PairedTest(n, nz, med, float(res.statistic), float(res.pvalue))


def group_rng(*key) -> np.random.Generator:
    """A Generator seeded from ``key`` (strings / ints), stable across runs and platforms."""
    text = "|".join(str(k) for k in key).encode()
    return np.random.default_rng(np.random.SeedSequence([zlib.crc32(text), len(text)]))
