"""The scene model's noise: the process noise of free objects out of view and the kernels that
jitter hidden objects after resampling (a regularised particle filter). Pure array functions; K
particles, M objects, metres, seconds, quaternions x, y, z, w."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from physics.transforms import quat_from_rotvec, quat_multiply

from ..belief import pose_stats
from ..config import NoiseConfig


def centred_normal(rng: np.random.Generator, std: float, shape: tuple[int, ...]) -> np.ndarray:
    """Normal draws of standard deviation ``std`` and ``shape (K, ...)`` whose mean over the K
    particles is exactly zero (moment-matched sampling): each draw minus the particles' mean, scaled
    by ``sqrt(K / (K - 1))`` so that each keeps the variance ``std ** 2``. A cloud drawn about a
    known mean then has that mean: an object never seen again (hidden from the start) is reported
    where its prior is, not ``std / sqrt(K)`` off by the chance of the draw, whatever K is. One
    particle (``K = 1``) gets a plain draw. The same random numbers are used as by
    ``rng.normal(0, std, shape)``."""
    drawn = rng.normal(0.0, std, shape)
    K = shape[0]
    if K < 2:
        return drawn
    return (drawn - drawn.mean(axis=0)) * math.sqrt(K / (K - 1))


def process_noise(poses: np.ndarray, free_unseen: np.ndarray, supported: np.ndarray, last_motion: np.ndarray,
                  dt: float, noise: NoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """In place on ``poses (K, M, 7)``, for the entries ``free_unseen (K, M)``: a random walk of
    ``process_position_std`` / ``process_orientation_std`` per sqrt(s) over ``dt`` seconds, plus
    model error of ``motion_noise`` times the distance ``last_motion (K, M)`` an object moved on or
    in its support (``supported (K, M)``) in the last update (rolling and sliding are chaotic;
    flight is not), capped at ``max_jitter_std``. An object on its support is moved along it only
    (horizontally, turned about the vertical): noise into the support or tilting it would be undone
    by the contact solver at the cost of the object's momentum, and a rolling ball or can would
    stop short. Returns the entries moved by more than 2 mm std ``(K, M)`` bool."""
    K, M = free_unseen.shape
    jolted = np.zeros((K, M), dtype=bool)
    if (noise.process_position_std > 0 or noise.motion_noise > 0) and np.any(free_unseen):
        rolling = np.where(supported, last_motion, 0.0)
        s = np.sqrt(noise.process_position_std ** 2 * dt + (noise.motion_noise * rolling) ** 2)
        s = np.minimum(s, noise.max_jitter_std)  # never through a wall
        step = rng.normal(0.0, 1.0, (K, M, 3)) * s[..., None]
        step[..., 2] = np.where(supported, 0.0, step[..., 2])  # its support holds it: along it only
        poses[..., :3] += np.where(free_unseen[..., None], step, 0.0)
        jolted = free_unseen & (s > 0.002)
    if noise.process_orientation_std > 0 and np.any(free_unseen):
        s = noise.process_orientation_std * math.sqrt(dt)
        rotvec = rng.normal(0.0, s, (K, M, 3))
        rotvec[..., :2] = np.where(supported[..., None], 0.0, rotvec[..., :2])  # on a support: about z only
        dq = quat_from_rotvec(rotvec)
        rotated = quat_multiply(dq, poses[..., 3:])
        poses[..., 3:] = np.where(free_unseen[..., None], rotated, poses[..., 3:])
    return jolted


class Kernel(NamedTuple):
    """A hidden object's regularisation kernel (:func:`regularisation_kernels`): the Cholesky
    factor ``chol (3, 3)`` (m) of the jitter's covariance ``beta^2 Sigma`` (``Sigma`` the object's
    weighted position covariance, ``beta`` the bandwidth after the cap), and ``shrink`` =
    ``sqrt(1 - beta^2)``, how far each copy is first drawn towards the cloud's mean (Liu and West,
    2001): ``x' = mean + shrink (x - mean) + jitter`` keeps the cloud's mean and covariance, where a
    plain jitter would add ``beta^2 Sigma`` to the covariance at every resampling."""

    chol: np.ndarray
    shrink: float


def regularisation_kernels(poses: np.ndarray, weights: np.ndarray, hidden: np.ndarray, bandwidth: float,
                           max_std: float) -> dict[int, Kernel]:
    """Per hidden object m (``hidden (M,)``) with a spread, its :class:`Kernel`: a jitter of
    ``bandwidth`` times the weighted covariance of ``poses (K, M, 7)`` under ``weights (K,)``
    (``bandwidth`` < 1), scaled down so that its largest std is at most ``max_std`` (m), and the
    shrinkage that keeps the covariance. Empty when ``bandwidth`` is 0."""
    kernels: dict[int, Kernel] = {}
    if bandwidth > 0:
        _, covs, _, _ = pose_stats(poses, weights)
        for m in np.flatnonzero(hidden):
            cov = covs[m]
            if np.trace(cov) > 1e-10:
                chol = np.linalg.cholesky(cov * bandwidth ** 2 + 1e-12 * np.eye(3))
                scale = min(1.0, max_std / np.sqrt(np.max(np.linalg.eigvalsh(cov)) * bandwidth ** 2))  # the cap
                kernels[int(m)] = Kernel(chol * scale, math.sqrt(max(0.0, 1.0 - (bandwidth * scale) ** 2)))
    return kernels
