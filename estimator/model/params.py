"""The particles' physical parameters: their bounds, and Liu-West shrinkage after resampling.

K particles, N objects, 5 parameters per object (:data:`~estimator.worlds.batch.PARAM_NAMES`: lateral,
rolling and spinning friction, restitution, mass in kg).

Frictions and masses are positive and known to a factor, not to a difference: they are shrunk and
jittered in log space (a kernel of 10 % moves a friction of 0.3 by 0.03 and one of 1.0 by 0.1);
restitution, which may be 0, in linear space. A parameter the prior perturbs keeps at least a spread
of ``param_floor`` (log units; linear for restitution) in the kernel, so that a resampling that
happened to keep a few particles for other reasons (an object's velocity, another object's
detection) does not fix it for good: what the evidence says later can still move it. The bounds are
the prior's range widened by ``param_reach`` (a factor): evidence may carry a parameter beyond what
the user's scene file and the prior allowed, not without limit.
"""
from __future__ import annotations

import math

import numpy as np

from ..config import EstimatorConfig

LOG_COLUMNS = (0, 1, 2, 4)
"""Columns jittered in log space: lateral, rolling and spinning friction, mass."""


def param_bounds(config: EstimatorConfig) -> np.ndarray:
    """Bounds ``(5, 2)`` (low, high) of the physical parameters: their prior ranges where perturbed,
    widened by ``NoiseConfig.param_reach`` (divided and multiplied; restitution at most 0.99), else
    ``[0, inf)``; masses at least 0.1 g."""
    nz = config.noise
    reach = nz.param_reach
    b = np.zeros((5, 2))
    for col, r in enumerate([nz.friction_range, nz.rolling_friction_range,
                             nz.spinning_friction_range, nz.restitution_range]):
        if r is None:
            b[col] = (0.0, np.inf)
        elif col == 3:
            b[col] = (r[0] / reach, min(0.99, r[1] * reach) if r[1] > 0 else 0.99)
        else:
            b[col] = (r[0] / reach, r[1] * reach)
    b[4] = (1e-4, np.inf)
    return b


def shrink_params(p: np.ndarray, h: float, bounds: np.ndarray, rng: np.random.Generator,
                  floor: float | np.ndarray = 0.0, spread: np.ndarray | None = None) -> np.ndarray:
    """Liu-West shrinkage of parameters ``p (K, N, 5)``: ``a x + (1 - a) mean + h std eps`` with
    ``a = sqrt(1 - h^2)``, ``x`` the parameter (its log for :data:`LOG_COLUMNS` where all particles
    have it positive), mean and std over the K particles (the spread is kept); where ``spread (N, 5)``
    bool says the prior perturbs it and its std is under ``floor`` (one, or ``(N, 5)``), plus normal noise of std
    ``sqrt(floor^2 - std^2)`` (the spread is restored to the floor). Clipped to ``bounds (5, 2)``.
    Two standard normal draws per entry when there is a floor, one without."""
    a = math.sqrt(1.0 - h * h)
    p = np.asarray(p, dtype=float)
    logs = np.zeros(p.shape[1:], dtype=bool)
    logs[:, list(LOG_COLUMNS)] = True
    logs &= np.all(p > 0, axis=0)
    x = np.where(logs[None], np.log(np.where(logs[None], p, 1.0)), p)
    mean = np.mean(x, axis=0)
    std = np.std(x, axis=0)
    x = a * x + (1 - a) * mean + h * std * rng.standard_normal(p.shape)
    floor = np.broadcast_to(np.asarray(floor, dtype=float), std.shape)
    if spread is not None and np.any(floor > 0):  # spread back to the floor what a resampling collapsed
        extra = np.where(spread, np.sqrt(np.maximum(floor * floor - std * std, 0.0)), 0.0)
        x = x + extra * rng.standard_normal(p.shape)
    out = np.where(logs[None], np.exp(x), x)
    return np.clip(out, bounds[:, 0], bounds[:, 1])
