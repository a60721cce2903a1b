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
from .noise import Kernel
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


def _free_mean(state: ParticleState, m: int, dims: int,
               weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Object ``m``'s free copies ``(K,)`` bool and the mean of their first ``dims`` coordinates
    (m; None when no copy is free, or none has weight), under ``weights (K,)`` (default equal)."""
    free = is_free(state.modes[:, m])
    if weights is None:
        return free, (state.poses[free, m, :dims].mean(axis=0) if np.any(free) else None)
    w = weights[free]
    return free, (w @ state.poses[free, m, :dims] / w.sum() if np.sum(w) > 0 else None)


def own_centres(state: ParticleState, own: np.ndarray) -> dict[int, np.ndarray]:
    """Where the free copies of each object ``own (M,)`` (each particle keeps its own values:
    :meth:`~estimator.model.SceneModel.before_resampling`) are on average horizontally, ``{m: (2,)}``
    (m), equal weights: nothing weighed them."""
    means = {m: _free_mean(state, m, 2)[1] for m in np.flatnonzero(own).tolist()}
    return {m: c for m, c in means.items() if c is not None}


def regularise(model, state: ParticleState, kernels: dict[int, Kernel], rng: np.random.Generator,
               centres: dict[int, np.ndarray] | None = None, rows: np.ndarray | None = None,
               weights: np.ndarray | None = None) -> np.ndarray:
    """In place, after resampling: jitter the free copies of each hidden object with its kernel (a
    regularised particle filter: copies of one particle must not leave a hidden object with no
    spread), drawn towards their mean first so that the cloud keeps its spread (Liu-West,
    :class:`~estimator.model.noise.Kernel`; a jitter into static geometry stops at its surface,
    ``static_clip``), then the physical parameters (Liu-West shrinkage, :func:`shrink_params`). A
    jittered entry is ``jolted`` (pushed out of what it penetrates before physics, loaded awake)
    unless it only slid along static geometry at rest (:func:`slid_at_rest`; its height is then its
    own again, the kernel's vertical part being a regulariser's micrometres for an object at rest on
    a support). ``centres``: for a resampling that changed K, where the free copies of each object
    that every particle kept (:func:`own_centres`) were on average before it; they are moved back
    there horizontally, every copy by the same shift, as a jitter is (a change of K drops the values
    of the particles beyond the new count, or repeats ancestors' values, and would move the average
    of a hidden object that nothing weighs by the chance of which). ``rows (K,)`` bool: only these
    particles are jittered and shrunk (default all; a growth by splitting jitters the new copies
    alone, :meth:`~estimator.model.SceneModel.after_growth`), towards means under ``weights (K,)``
    (default equal, as after a resampling). Returns ``(K, M)`` bool: the entries that slid."""
    slid = np.zeros((model.K, model.M), dtype=bool)
    jittered, start = [], state.poses.copy()
    shifts = []  # (object, its free copies (K,), each copy's shift (K, 3))
    for m, centre in (centres or {}).items():
        free, mean = _free_mean(state, m, 2)
        if mean is not None:
            gap = centre - mean
            shifts.append((m, free, np.broadcast_to([gap[0], gap[1], 0.0], (model.K, 3))))
    for m, kernel in kernels.items():
        jitter = rng.standard_normal((model.K, 3)) @ kernel.chol.T
        free, mean = _free_mean(state, m, 3, weights)
        if mean is not None:  # Liu-West: towards the mean first, or the jitter widens the cloud
            jitter[free] += (kernel.shrink - 1.0) * (state.poses[free, m, :3] - mean)
        shifts.append((m, free if rows is None else free & rows, jitter))
    for m, free, noise in shifts:
        before = state.poses[free, m].copy()
        was = state.jolted[free, m].copy()
        state.poses[free, m, :3] += noise[free]
        state.jolted[free, m] = True
        if model.geometry is not None and np.any(free):  # not into the table or under the floor
            state.poses[free, m] = model.geometry.clip(m, before, state.poses[free, m])[0]
            jittered.append((m, np.flatnonzero(free), before, ~was))
    for m, rows, before, fresh in jittered:  # once every object has its jitter (they must not meet)
        still = slid_at_rest(model, state, m, rows, before, fresh, start)
        state.poses[rows[still], m, 2] = before[still, 2]
        state.jolted[rows[still], m] = False
        slid[rows[still], m] = True
    nz = model.config.noise
    if nz.param_jitter > 0:
        dyn = np.flatnonzero(model.dynamic)
        floor = np.full((len(dyn), 5), nz.param_floor)
        floor[model.surprise[dyn] > SURPRISE, :2] = nz.param_widen  # frictions: surprised by its motion
        state.params[:, dyn] = shrink_params(state.params[:, dyn], nz.param_jitter, model.param_bounds, rng,
                                             floor, model.perturbed[dyn], rows, weights)
    return slid


SLIDE_MARGIN = 0.02
"""m: the clearance a jittered object needs from every other object's box and from every static
body but its support (:func:`slid_at_rest`), and how far under it its support is looked for:
more than Bullet's contact distance."""

SLIDE_TOLERANCE = 1e-5
"""m: how far what lies under an object slid along static geometry may differ from what lay
under it before (:func:`slid_at_rest`: the ray tests' rounding), and how far the jitter may have
moved it vertically (the kernel's regulariser, 1e-6 m of standard deviation, for an object at
rest on a support: :func:`~estimator.model.noise.regularisation_kernels`)."""

SUPPORT_TOP = 0.002
"""m: how far above where it holds an object slid at rest its static support's box may reach
(:func:`slid_at_rest`: no rim, wall or bump of the support's own body; pybullet's boxes of a
URDF's bodies are a millimetre larger than their shapes)."""


def slid_at_rest(model, state: ParticleState, m: int, rows: np.ndarray, before: np.ndarray,
                 fresh: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """Of object ``m``'s copies ``rows (n,)`` that the regularisation jittered from the link-frame
    poses ``before (n, 7)`` to ``state.poses[rows, m]``, those that only slid along static geometry
    at rest, and so are at rest where they are as surely as a world that made them at rest there
    would have them, at their height before: ``(n,)`` bool.

    Such a copy is ``fresh (n,)`` (not displaced without physics since a world made it) and at rest
    (velocity exactly zero, as the worlds leave what sleeps); its orientation is unchanged and its
    height within :data:`SLIDE_TOLERANCE` (the jitter moved it horizontally, and no static surface
    stopped it); in its particle it rests on static bodies or the floor only, nothing rests on or
    in it and it is in nothing; no other known dynamic object's box comes within
    :data:`SLIDE_MARGIN` of its own (:meth:`~physics.penetration.StaticGeometry.box`), before (the
    others where they were then: ``start (K, M, 7)``, the poses before any jitter; default the
    state's) or after. And the static geometry around it is the same: one static body holds it up
    under the centre and the corners of its box, before and after, at the same heights with the
    same normals (to :data:`SLIDE_TOLERANCE`; :meth:`~physics.penetration.StaticGeometry.under`),
    that body's box reaches no more than :data:`SUPPORT_TOP` above where it holds it, and no other
    static body's box comes within :data:`SLIDE_MARGIN` of its own. A flat table top under the
    whole of it gives that; an edge, a slope, a step, a rim or a wall within reach does not.

    Physics would keep it where it is: it can be loaded asleep
    (:meth:`~estimator.worlds.pool.WorldPool.follow`), and it costs its world no settling (a duck
    woken at every resampling of ``cluttered_table`` cost a whole update of Bullet's steps in every
    world). A few array operations and one batch of ray tests for all the copies."""
    after = state.poses[rows, m]
    ok = np.asarray(fresh, dtype=bool) & np.any(after[:, :2] != before[:, :2], axis=1)
    on = state.on_top[rows, m]  # (n, M + 1): the last column is the floor
    fixed = np.append(model.static, True)
    ok &= on.any(axis=1) & ~np.any(on & ~fixed, axis=1)
    ok &= ~state.is_in[rows, m].any(axis=1)  # in nothing, and nothing in or on it
    ok &= ~state.is_in[rows, :, m].any(axis=1) & ~state.on_top[rows, :, m].any(axis=1)
    start = state.poses if start is None else start
    idx = np.flatnonzero(ok)
    ok[idx] = _slides(model, m, before[idx], after[idx], state.velocities[rows[idx], m], start[rows[idx]],
                      state.poses[rows[idx]])
    return ok


def _slides(model, m: int, before: np.ndarray, after: np.ndarray, velocities: np.ndarray,
            others_before: np.ndarray, others_after: np.ndarray) -> np.ndarray:
    """Whether object ``m``, moved from the link-frame poses ``before (n, 7)`` to ``after (n, 7)``,
    only slid along the static geometry it rests on, clear of everything else, and is still:
    ``(n,)`` bool (see :func:`slid_at_rest`: its orientation the same, its height within
    :data:`SLIDE_TOLERANCE`, where it is judged, its ``velocities (n, 6)`` exactly zero;
    ``others_before`` and ``others_after (n, M, 7)`` are where the other objects were and are)."""
    geometry, M = model.geometry, model.M
    ok = (np.abs(after[:, 2] - before[:, 2]) <= SLIDE_TOLERANCE) & np.all(after[:, 3:] == before[:, 3:], axis=1)
    ok &= ~np.any(velocities != 0.0, axis=1)
    after = after.copy()
    after[:, 2] = before[:, 2]  # judged at its own height
    for p, where in ((before, others_before), (after, others_after)):  # boxes apart by the margin, on some axis
        if not ok.any():
            return ok
        lo, hi = geometry.box(m, p)
        for o in np.flatnonzero(model.dynamic & model.known & (np.arange(M) != m)).tolist():
            lo_o, hi_o = geometry.box(o, where[:, o])
            ok &= np.any((lo - hi_o > SLIDE_MARGIN) | (lo_o - hi > SLIDE_MARGIN), axis=1)
    if not ok.any():
        return ok
    idx = np.flatnonzero(ok)
    # the poses before asked once each (the copies of one particle share theirs), then those after
    first, back = np.unique(before[idx], axis=0, return_inverse=True)
    back = back.reshape(-1)
    both = np.concatenate([first, after[idx]])
    under = geometry.under(m, both, SLIDE_MARGIN)  # (u + n, 5, 5)
    old, new = under[:len(first)][back], under[len(first):]
    body = old[:, 0, 0].astype(int)
    same = (body >= 0) & np.all(old[..., 0] == body[:, None], axis=1) & np.all(new[..., 0] == old[..., 0], axis=1)
    same &= np.all(np.abs(new[..., 1:] - old[..., 1:]) <= SLIDE_TOLERANCE, axis=(1, 2))
    same &= np.all(old[..., 1] >= geometry.static_top(np.maximum(body, 0))[:, None] - SUPPORT_TOP, axis=1)
    near = geometry.near_static(m, both, SLIDE_MARGIN)  # (u + n, S)
    others = np.concatenate([near[:len(first)][back], near[len(first):]])  # (2 n, S): before, after
    others[np.arange(2 * len(idx)), np.concatenate([np.maximum(body, 0)] * 2)] = False
    same &= ~others[:len(idx)].any(axis=1) & ~others[len(idx):].any(axis=1)
    ok[idx[~same]] = False
    return ok


def placed_at_rest(model, poses: np.ndarray, velocities: np.ndarray, modes: np.ndarray, flat: np.ndarray,
                   prior: np.ndarray) -> np.ndarray:
    """The entries that the particles' first placement left at rest, ``(K, M)`` bool: objects
    ``flat (M,)`` (resting flat on static bodies alone at their poses ``prior (M, 7)``,
    :func:`~estimator.model.prior.rest_prior`) that each particle, at ``poses (K, M, 7)``, has free
    and still (zero velocity) at the prior's height (within :data:`SLIDE_TOLERANCE`, set back to it
    in place) and orientation, moved along their support by the perturbation or a first sighting
    only, clear of every other object (:func:`_slides`, the others where the prior and the particle
    have them). Physics would keep each where it is: its worlds load it asleep and need not settle
    it (the hidden duck of ``cluttered_table`` rocked in every world for the first three updates,
    each a whole update of Bullet's steps)."""
    placed = np.zeros(poses.shape[:2], dtype=bool)
    for m in np.flatnonzero(flat & model.dynamic & model.known).tolist():
        ok = is_free(modes[:, m])
        idx = np.flatnonzero(ok)
        ok[idx] = _slides(model, m, np.broadcast_to(prior[m], (len(idx), 7)), poses[idx, m], velocities[idx, m],
                          np.broadcast_to(prior, (len(idx),) + prior.shape), poses[idx])
        poses[ok, m, 2] = prior[m, 2]
        placed[:, m] = ok
    return placed


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
