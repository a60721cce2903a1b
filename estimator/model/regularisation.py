"""After resampling: the jitter of hidden objects and the shrinkage of the physical parameters; and
the recovery when every particle has zero weight.

Functions of the scene model (:class:`~estimator.model.SceneModel`, passed as ``model``): K particles,
M objects; positions in metres.
"""
from __future__ import annotations

import numpy as np

from actions.modes import is_free

from ..resampling import effective_sample_size
from ..state import ParticleState
from ..worlds.resting import slow
from .noise import regularisation_kernels as kernels_of
from .params import shrink_params
from .step import Settled
from .weighing import SURPRISE


def reseed(model, poses: np.ndarray, vel: np.ndarray, detected: np.ndarray, rng: np.random.Generator) -> None:
    """Recovery when every particle has zero weight, in place: detected objects ``(M,)`` are put at
    their perceived position (plus ``position_std`` noise), at rest."""
    idx = np.flatnonzero(detected & model.dynamic)
    if len(idx):
        poses[:, idx, :3] = model.memory.last_pose[idx, :3]
        if model.config.noise.position_std > 0:
            poses[:, idx, :3] += rng.normal(0.0, model.config.noise.position_std, (model.K, len(idx), 3))
        vel[:, idx] = 0.0


def unweighable(model, settled: Settled) -> np.ndarray:
    """Objects ``(M,)`` whose particles physics cannot tell apart by what else happens: free and at
    rest on a support in every particle, and no other object on or in them in any particle."""
    at_rest = settled.supported & slow(settled.velocities)
    parent = settled.on_top[..., :model.M].any(axis=1) | settled.is_in.any(axis=1)
    return np.all(is_free(settled.modes) & at_rest & ~parent, axis=0)


def regularisation_kernels(model, poses: np.ndarray, weights: np.ndarray,
                           hidden: np.ndarray) -> dict[int, np.ndarray]:
    """The jitter kernels of the hidden objects ``hidden (M,)`` after resampling
    (:func:`~estimator.model.noise.regularisation_kernels`), from their spread under ``weights (K,)``
    mixed with equal weights in proportion ``1 - ESS / K``: weights that leave few particles
    are mostly about other objects (a cube picked up in plain view can give one particle all the
    weight), and a kernel sized by them alone would leave a hidden object that particle's one
    value. What the weights do say about a hidden object (negative evidence) they say again at
    the next update to the jittered copies."""
    nz = model.config.noise
    K = len(weights)
    share = effective_sample_size(weights) / K
    mixed = share * weights + (1.0 - share) / K
    return kernels_of(poses, mixed, hidden, nz.regularisation, nz.max_jitter_std)


def regularise(model, state: ParticleState, kernels: dict[int, np.ndarray], rng: np.random.Generator) -> None:
    """In place, after resampling: jitter the free copies of each hidden object with its kernel (a
    regularised particle filter: copies of one particle must not leave a hidden object with no
    spread; a jitter into static geometry stops at its surface, ``static_clip``), then the
    physical parameters (Liu-West shrinkage, :func:`shrink_params`)."""
    for m, chol in kernels.items():
        free = is_free(state.modes[:, m])
        noise = rng.standard_normal((model.K, 3)) @ chol.T
        before = state.poses[free, m].copy()
        state.poses[free, m, :3] += noise[free]
        state.jolted[free, m] = True
        if model.geometry is not None and np.any(free):  # not into the table or under the floor
            state.poses[free, m] = model.geometry.clip(m, before, state.poses[free, m])[0]
    nz = model.config.noise
    if nz.param_jitter > 0:
        dyn = np.flatnonzero(model.dynamic)
        floor = np.full((len(dyn), 5), nz.param_floor)
        floor[model.surprise[dyn] > SURPRISE, :2] = nz.param_widen  # frictions: surprised by its motion
        state.params[:, dyn] = shrink_params(state.params[:, dyn], nz.param_jitter, model.param_bounds, rng,
                                             floor, model.perturbed[dyn])
