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

A particle's parameters mean what the scene file states; :func:`world_params` gives what the Bullet
worlds must be set to for it (a rolling friction depends, in Bullet, on what the object rests on).
"""
from __future__ import annotations

import math

import numpy as np

from physics.bodies import bullet_rolling_friction
from physics.settings import FLOOR_FRICTION

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
                  floor: float | np.ndarray = 0.0, spread: np.ndarray | None = None,
                  rows: np.ndarray | None = None, weights: np.ndarray | None = None) -> np.ndarray:
    """Liu-West shrinkage of parameters ``p (K, N, 5)``: ``a x + (1 - a) mean + h std eps`` with
    ``a = sqrt(1 - h^2)``, ``x`` the parameter (its log for :data:`LOG_COLUMNS` where all particles
    have it positive), mean and std over the K particles (the spread is kept); where ``spread (N, 5)``
    bool says the prior perturbs it and its std is under ``floor`` (one, or ``(N, 5)``), plus normal noise of std
    ``sqrt(floor^2 - std^2)`` (the spread is restored to the floor). Clipped to ``bounds (5, 2)``.
    Two standard normal draws per entry when there is a floor, one without. ``rows (K,)`` bool:
    only these particles are shrunk (the others returned as they are; draws for these alone), and
    ``weights (K,)`` normalised: the mean and std are weighted (default equal)."""
    a = math.sqrt(1.0 - h * h)
    p = np.asarray(p, dtype=float)
    logs = np.zeros(p.shape[1:], dtype=bool)
    logs[:, list(LOG_COLUMNS)] = True
    logs &= np.all(p > 0, axis=0)
    x = np.where(logs[None], np.log(np.where(logs[None], p, 1.0)), p)
    if weights is None:
        mean = np.mean(x, axis=0)
        std = np.std(x, axis=0)
    else:
        mean = np.tensordot(weights, x, axes=1)
        std = np.sqrt(np.tensordot(weights, (x - mean) ** 2, axes=1))
    whole = rows is None
    sel = x if whole else x[rows]
    sel = a * sel + (1 - a) * mean + h * std * rng.standard_normal(sel.shape)
    floor = np.broadcast_to(np.asarray(floor, dtype=float), std.shape)
    if spread is not None and np.any(floor > 0):  # spread back to the floor what a resampling collapsed
        extra = np.where(spread, np.sqrt(np.maximum(floor * floor - std * std, 0.0)), 0.0)
        sel = sel + extra * rng.standard_normal(sel.shape)
    out = np.where(logs[None], np.exp(sel), sel)
    out = np.clip(out, bounds[:, 0], bounds[:, 1])
    if whole:
        return out
    full = p.copy()
    full[rows] = out
    return full


def resting_friction(params: np.ndarray, on_top: np.ndarray, is_in: np.ndarray,
                     floor_friction: float = FLOOR_FRICTION) -> np.ndarray:
    """Lateral friction ``(K, M)`` of what each particle's object rests on, from the particles'
    relations (:func:`physics.bodies.support_friction` reads it from a world's contacts): the mean over the
    containers it is in (``is_in (K, M, M)``: a container's floor holds it, whatever else its box
    overlaps), else over what it is on top of (``on_top (K, M, M+1)``, column M the floor, of friction
    ``floor_friction``), their frictions the particle's (``params (K, M, 5)``, column 0); NaN where it
    rests on nothing."""
    M = params.shape[1]
    inside = np.any(is_in, axis=-1, keepdims=True)
    under = np.where(inside, is_in, on_top[..., :M])
    on_floor = on_top[..., M] & ~inside[..., 0]
    total = np.einsum("kmj,kj->km", under.astype(float), params[..., 0]) + on_floor * floor_friction
    n = under.sum(axis=-1) + on_floor
    return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def world_params(params: np.ndarray, on_top: np.ndarray, is_in: np.ndarray,
                 floor_friction: float = FLOOR_FRICTION) -> np.ndarray:
    """The parameters ``(K, M, 5)`` to set in the Bullet worlds for the particles' ``params (K, M,
    5)``: the same, but each rolling friction is what Bullet needs to realise it on the support the
    object rested on at the last update (:func:`resting_friction` from ``on_top (K, M, M+1)`` and
    ``is_in (K, M, M)``; :func:`physics.bodies.bullet_rolling_friction`): the stated coefficient is a
    contact's resisting torque per newton on any support, as MuJoCo and the truth simulator realise
    it. Returns ``params`` itself when nothing changes."""
    mu = resting_friction(params, on_top, is_in, floor_friction)
    rolling = bullet_rolling_friction(params[..., 1], mu)
    if np.array_equal(rolling, params[..., 1]):
        return params
    out = params.copy()
    out[..., 1] = rolling
    return out
