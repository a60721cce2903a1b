"""The particles' physical parameters: their bounds, and Liu-West shrinkage after resampling.

K particles, N objects, 5 parameters per object (:data:`~estimator.propagate.PARAM_NAMES`: lateral,
rolling and spinning friction, restitution, mass in kg).
"""
from __future__ import annotations

import math

import numpy as np

from .config import EstimatorConfig


def param_bounds(config: EstimatorConfig) -> np.ndarray:
    """Bounds ``(5, 2)`` (low, high) of the physical parameters: their prior ranges where perturbed,
    else ``[0, inf)``; masses at least 0.1 g."""
    nz = config.noise
    b = np.zeros((5, 2))
    for col, r in enumerate([nz.friction_range, nz.rolling_friction_range,
                             nz.spinning_friction_range, nz.restitution_range]):
        b[col] = r if r is not None else (0.0, np.inf)
    b[4] = (1e-4, np.inf)
    return b


def shrink_params(p: np.ndarray, h: float, bounds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Liu-West shrinkage of parameters ``p (K, N, 5)``: ``a p + (1 - a) mean + h std eps`` with
    ``a = sqrt(1 - h^2)`` (mean and std over the K particles; keeps both while avoiding collapse),
    clipped to ``bounds (5, 2)``."""
    a = math.sqrt(1.0 - h * h)
    mean = np.mean(p, axis=0)
    std = np.std(p, axis=0)
    p = a * p + (1 - a) * mean + h * std * rng.standard_normal(p.shape)
    return np.clip(p, bounds[:, 0], bounds[:, 1])
