"""After resampling: the jitter of hidden objects and the shrinkage of the physical parameters, what
was carried along at rest; and the recovery when every particle has zero weight.

Functions of the scene model (:class:`~estimator.model.SceneModel`, passed as ``model``): K particles,
M objects; positions in metres.
"""
from __future__ import annotations

import numpy as np

from actions.modes import is_free
from physics.transforms import quat_conjugate, quat_multiply, quat_rotate

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


LEVEL_TILT = 1e-3
"""rad: the most the support of an object carried along at rest (:func:`carried_at_rest`) may turn
away from the vertical between the particle and its ancestor (a support tilted further could set
what rests on it rolling)."""


def bounding_radii(boxes: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Radii ``(M,)`` (m) of spheres about ``positions (M, 3)`` that hold each object, from its
    bounding box ``boxes (M, 2, 3)`` read at that position (whatever the object's orientation
    later, it stays within). Where a position is not finite (an object the scene does not place),
    the box's half diagonal is taken as the offset of its centre too."""
    centre, half = boxes.mean(axis=1), np.linalg.norm(0.5 * (boxes[:, 1] - boxes[:, 0]), axis=-1)
    offset = np.linalg.norm(centre - positions, axis=-1)
    return half + np.where(np.isfinite(offset), offset, half)


def carried_at_rest(model, before: ParticleState, after: ParticleState, ancestors: np.ndarray, own: np.ndarray,
                    radii: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The entries that resampling carried along at rest (:meth:`~estimator.state.ParticleState.take`:
    an object each particle keeps, ``own (M,)``, carried rigidly with the support it rests on or in
    from the particle's pose of that support to the ancestor's), as ``(mask (n, M), after.poses)``
    for :meth:`~estimator.worlds.pool.WorldPool.follow` (None if there are none): they may be loaded
    asleep, as a world at rest would have produced them. An entry qualifies when the object and its
    support were at rest (zero velocity, as the worlds leave what sleeps) in the particle and the
    support is in the ancestor; the support is dynamic, resampled (not kept itself) and turned only
    about the vertical (within :data:`LEVEL_TILT`): on it the object rests as it did; and no other
    known dynamic object's bounding sphere (``radii (M,)``, m) meets the object's where it is carried: it
    penetrates nothing it did not before (the marble in the bin of ``cluttered_table``, which was
    loaded awake at every resampling and woke the bin for a whole update in every world)."""
    n, M = min(len(ancestors), len(before.poses)), model.M
    idx = np.flatnonzero(own & model.dynamic)
    if len(idx) == 0:
        return None
    support = before.is_in[:n, idx] | before.on_top[:n, idx, :M]  # (n, len(idx), M), as take() carries
    k, j = np.nonzero(support.any(axis=-1))
    if len(k) == 0:
        return None
    m, c = idx[j], np.argmax(support[k, j], axis=-1)
    ok = model.dynamic[c] & ~own[c]
    still = ~np.any(before.velocities != 0.0, axis=-1)  # (K, M): at rest, as the worlds leave it
    ok &= still[k, m] & still[k, c] & ~np.any(after.velocities[k, c] != 0.0, axis=-1)
    turn = quat_multiply(after.poses[k, c, 3:], quat_conjugate(before.poses[k, c, 3:]))
    up = quat_rotate(turn, np.broadcast_to([0.0, 0.0, 1.0], turn.shape[:-1] + (3,)))
    ok &= up[:, 2] > np.cos(LEVEL_TILT)
    cols = np.arange(M)[None, :]
    others = (model.dynamic & model.known)[None, :] & (cols != m[:, None]) & (cols != c[:, None])
    centres = np.linalg.norm(after.poses[k, :, :3] - after.poses[k, m, None, :3], axis=-1)
    gap = centres - radii[m][:, None] - radii[None]
    ok &= ~np.any(others & ~(gap > 0.0), axis=-1)
    if not ok.any():
        return None
    mask = np.zeros((len(after.poses), M), dtype=bool)
    mask[k[ok], m[ok]] = True
    return mask, after.poses
