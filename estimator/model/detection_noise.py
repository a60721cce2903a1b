"""The tracker's position noise, measured from its own detections.

How far a detection may stray from where a still object rests before the object counts as moved
(:attr:`~estimator.model.perception_memory.PerceptionMemory.moving_since`) depends on the tracker: 1.5 cm
is five standard deviations of a 3 mm tracker and one and a half of a 1 cm one, which would see every
resting object start moving every other frame. Rather than a threshold fitted on one tracker, the
perception memory measures the noise: each object's detections over the last fraction of a second
are fitted by a straight line (its perceived velocity), and the scatter of the detections about that
line is an estimate of the noise with ``2 (n - 2)`` degrees of freedom (two horizontal axes, two
parameters per axis). :class:`DetectionNoise` pools these estimates over objects and recent updates
with a median, so that the few objects accelerating at any time (whose scatter about a line is also
the curve of their path) do not count, and :func:`onset_distance` turns it into a distance a fresh
detection of a still object exceeds by chance once in a thousand times.

Pure numpy and scipy; nothing here knows the scene.
"""

from __future__ import annotations

import functools
import math
from collections import deque

import numpy as np

from ..belief import chi2_quantile

ONSET_FALSE_ALARM = 1e-3
"""Probability that one detection of a still object lies beyond :func:`onset_distance` of its
resting position by noise alone (three axes, Gaussian)."""

ONSET_SIGMAS = math.sqrt(float(chi2_quantile(1.0 - ONSET_FALSE_ALARM, 3)))
"""The onset distance in noise standard deviations per axis: the square root of the chi-square
(3 degrees of freedom) quantile at ``1 - ONSET_FALSE_ALARM`` (about 4.03)."""


def onset_distance(noise_std: float, floor: float) -> float:
    """Distance (m) from a still object's resting position beyond which a detection says it moved:
    ``ONSET_SIGMAS * noise_std`` (``noise_std`` in m per axis), and never under ``floor`` (m); NaN
    ``noise_std`` (not measured yet) gives ``floor``."""
    if not math.isfinite(noise_std):
        return floor
    return max(floor, ONSET_SIGMAS * noise_std)


class DetectionNoise:
    """Running robust estimate of a tracker's position noise (m, standard deviation per axis).

    :meth:`add` takes one object's scatter about its fitted line (m, RMS per axis) and its degrees of
    freedom; :attr:`std` is the median over the last ``window`` of them of ``scatter^2 / m_k``, where
    ``m_k`` is the median of a chi-square variable with ``k`` degrees of freedom over ``k`` (the
    median of a scatter from Gaussian noise of variance ``s^2`` is ``s^2 m_k``), square-rooted; NaN
    until ``min_samples`` have been added.
    """

    def __init__(self, window: int = 64, min_samples: int = 8):
        if window < 1 or not 1 <= min_samples <= window:
            raise ValueError(f"DetectionNoise needs window >= 1 and 1 <= min_samples <= window, got {window}, {min_samples}")
        self.min_samples = int(min_samples)
        self._samples: deque[float] = deque(maxlen=int(window))
        self._std: float | None = None  # the median of the samples, taken when read (std)

    def add(self, scatter: float, dof: int) -> None:
        """One scatter (m per axis) over ``dof`` degrees of freedom; non-finite values or ``dof < 1``
        are ignored."""
        if dof < 1 or not math.isfinite(scatter):
            return
        self._samples.append(scatter * scatter / _median_ratio(int(dof)))
        self._std = None  # taken again when read (an update adds one per object seen)

    @property
    def std(self) -> float:
        """The estimate (m per axis); NaN before ``min_samples`` scatters."""
        if self._std is None:
            self._std = (math.sqrt(float(np.median(np.fromiter(self._samples, dtype=float))))
                         if len(self._samples) >= self.min_samples else math.nan)
        return self._std

    def __len__(self) -> int:
        return len(self._samples)


@functools.lru_cache(maxsize=None)
def _median_ratio(k: int) -> float:
    """Median of a chi-square variable with ``k`` degrees of freedom, over ``k``."""
    return float(chi2_quantile(0.5, k)) / k
