"""The belief: what the weighted particles say about every object, and its JSON form.

Per object: discrete hypotheses grouped by support ("on the floor" 0.8, "in blue_box" 0.2, "held"),
the headline position (the most probable hypothesis's weighted mean and covariance), the overall
weighted mean position and covariance, the weighted chordal mean orientation and angular spread,
P(isPhysicallyPlausible), P(held). Per pair: relation probabilities. Per update: events.

A belief with several modes reports the most probable one as its position, never the average of
the modes (a cup half held, half on the floor is not in the air between them); with one mode the
two coincide.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import fdtri, gammaincinv

from actions.events import EventRecord
from actions.modes import is_held
from physics.transforms import quat_angle

from .relations import relation_list


@dataclass(frozen=True)
class Hypothesis:
    """A group of particles agreeing on where an object is: ``relation`` is ``"isOnTop"``,
    ``"isIn"``, ``"held"`` or ``"none"`` (airborne / unsupported), ``support`` the object it rests on or
    is in (``"floor"`` for the floor; ``None`` for held / none), ``p`` the group's weight and
    ``position (3,)`` its weighted mean position (m)."""

    p: float
    relation: str
    support: str | None
    position: np.ndarray

    def to_json(self) -> dict:
        return {"p": round(float(self.p), 4), "relation": self.relation, "support": self.support,
                "position": _r(self.position)}


@dataclass(frozen=True)
class ObjectBelief:
    """Belief about one object.

    ``position (3,)`` m and ``position_cov (3, 3)`` m^2: the weighted mean and covariance of the
    particles of the most probable hypothesis (``hypotheses[0]``); ``mean_position (3,)`` and
    ``mean_position_cov (3, 3)``: those of all particles (equal to the former when every particle
    agrees on the support). ``orientation (4,)`` x,y,z,w and ``angular_std`` rad (weighted RMS
    angle to it) are the weighted chordal mean over all particles. ``mean_position`` ``None``
    (objects built by hand) means ``position``. ``person`` (only when the scene names a person):
    ``{"id", "p_visible", "p_reachable"}`` (:mod:`estimator.applications.person`). ``position_dof``: the
    position is a multivariate Student-t with these degrees of freedom and covariance
    ``position_cov`` (``inf``: Gaussian); :meth:`region` gives its ellipsoids. ``parameters`` (dynamic
    objects): the posterior of its physical parameters over the particles, ``{name: (mean, std)}``
    for :data:`REPORTED_PARAMETERS` (lateral and rolling friction, restitution; mass in kg).
    """

    position: np.ndarray
    orientation: np.ndarray
    position_cov: np.ndarray
    angular_std: float
    perceived: bool
    p_plausible: float
    p_held: float
    hypotheses: tuple[Hypothesis, ...] = ()
    mean_position: np.ndarray | None = None
    mean_position_cov: np.ndarray | None = None
    person: dict | None = None
    position_dof: float = math.inf
    parameters: dict | None = None

    def region(self, level: float) -> float:
        """Squared Mahalanobis radius ``r2`` (with respect to ``position_cov``) of the ellipsoid
        ``(x - position)^T position_cov^-1 (x - position) <= r2`` that holds the object with
        probability ``level`` (in (0, 1)) under the reported distribution."""
        return float(region_radius_sq(level, self.position_dof))

    def to_json(self) -> dict:
        mean = self.position if self.mean_position is None else self.mean_position
        mean_cov = self.position_cov if self.mean_position_cov is None else self.mean_position_cov
        out = {"position": _r(self.position), "orientation": _r(self.orientation),
               "position_cov": [_r(row, 8) for row in self.position_cov],
               "mean_position": _r(mean), "mean_position_cov": [_r(row, 8) for row in mean_cov],
               "angular_std": round(float(self.angular_std), 6), "perceived": bool(self.perceived),
               "p_plausible": round(float(self.p_plausible), 4), "p_held": round(float(self.p_held), 4),
               "hypotheses": [h.to_json() for h in self.hypotheses],
               "position_dof": None if math.isinf(self.position_dof) else round(float(self.position_dof), 4)}
        if self.person is not None:
            out["person"] = self.person
        if self.parameters is not None:
            out["parameters"] = {k: {"mean": round(float(mu), 6), "std": round(float(sd), 6)}
                                 for k, (mu, sd) in self.parameters.items()}
        return out


@dataclass(frozen=True)
class Belief:
    """The estimator's output at time ``t`` (s), one line of the estimate stream.

    ``particles`` ``(K, M, 7)`` poses and ``weights`` ``(K,)`` are kept for visualisation and search;
    ``object_ids`` names the M columns. ``n_particles``: with an adaptive particle count, the K of
    this update (written to the stream as ``particles``); 0 otherwise (not written).
    """

    t: float
    objects: dict[str, ObjectBelief]
    relations: list[dict]
    events: list[EventRecord]
    ess: float
    object_ids: tuple[str, ...] = ()
    particles: np.ndarray | None = field(default=None, repr=False)
    weights: np.ndarray | None = field(default=None, repr=False)
    n_particles: int = 0

    def to_json(self) -> dict:
        out = {"t": round(float(self.t), 6),
               "objects": {k: v.to_json() for k, v in self.objects.items()},
               "relations": self.relations,
               "events": [e.to_json() for e in self.events],
               "ess": round(float(self.ess), 3)}
        if self.n_particles:
            out["particles"] = int(self.n_particles)
        return out

    def relation_p(self, subject: str, predicate: str, obj: str) -> float:
        """Probability of a relation (0 when it is not listed)."""
        for r in self.relations:
            if (r["subject"], r["predicate"], r["object"]) == (subject, predicate, obj):
                return float(r["p"])
        return 0.0

    def hypothesis_p(self, subject: str, relation: str, support: str | None) -> float:
        """Probability of one hypothesis of ``subject`` (0 when absent)."""
        for h in self.objects[subject].hypotheses:
            if h.relation == relation and h.support == support:
                return float(h.p)
        return 0.0


def headline_positions(belief: Belief) -> np.ndarray:
    """Headline positions ``(M, 3)`` m of ``belief`` in ``belief.object_ids`` order (NaN for objects
    it leaves out)."""
    out = np.full((len(belief.object_ids), 3), np.nan)
    for m, oid in enumerate(belief.object_ids):
        if oid in belief.objects:
            out[m] = belief.objects[oid].position
    return out


def with_added_variance(belief: Belief, variance: np.ndarray) -> Belief:
    """``belief`` with ``variance (M,)`` m^2 (``belief.object_ids`` order) added to the diagonal of
    each object's ``position_cov`` and ``mean_position_cov`` (0 leaves it as it is)."""
    variance = np.asarray(variance, float)
    if variance.shape != (len(belief.object_ids),) or not np.all(np.isfinite(variance) & (variance >= 0)):
        raise ValueError(f"variance must be ({len(belief.object_ids)},), finite and >= 0, got {variance!r}")
    objects = dict(belief.objects)
    for m, oid in enumerate(belief.object_ids):
        if oid in objects and variance[m] > 0:
            o = objects[oid]
            add = variance[m] * np.eye(3)
            mean_cov = o.position_cov if o.mean_position_cov is None else o.mean_position_cov
            objects[oid] = replace(o, position_cov=o.position_cov + add, mean_position_cov=mean_cov + add)
    return replace(belief, objects=objects)


def region_radius_sq(level, dof, dim: int = 3):
    """Squared Mahalanobis radius of the ``level`` region of a ``dim``-variate Student-t with
    ``dof`` degrees of freedom (> 2; ``inf``: Gaussian), measured with its covariance (not its scale
    matrix, which is ``cov * (dof - 2) / dof``). ``level`` and ``dof`` broadcast; returns an array
    (a float for scalars). For a Gaussian it is ``chi2.ppf(level, dim)``; for a t it is
    ``dim * (dof - 2) / dof * F.ppf(level, dim, dof)``, the distance over the scale matrix being
    ``dim`` times an F(dim, dof) variable."""
    level, dof = np.broadcast_arrays(np.asarray(level, float), np.asarray(dof, float))
    if np.any((level <= 0) | (level >= 1)) or np.any(~(dof > 2)):
        raise ValueError(f"region_radius_sq: level must be in (0, 1) and dof > 2, got {level!r}, {dof!r}")
    finite = np.isfinite(dof)
    d = np.where(finite, dof, 3.0)
    out = np.where(finite, dim * (d - 2.0) / d * fdtri(dim, d, level), chi2_quantile(level, dim))
    return out[()] if out.ndim == 0 else out


def chi2_quantile(level, dof):
    """The ``level`` quantile of a chi-square variable with ``dof`` degrees of freedom (``level``
    and ``dof`` broadcast; an array, or a float for scalars): ``scipy.stats.chi2.ppf``'s value, from
    :mod:`scipy.special` (importing :mod:`scipy.stats` costs about a second of start-up)."""
    return 2.0 * gammaincinv(np.multiply(0.5, dof), level)


def _r(values, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(values).ravel()]


def support_labels(modes: np.ndarray, on_top: np.ndarray, is_in: np.ndarray) -> np.ndarray:
    """Integer support label ``(K, M)`` per particle and object.

    0: held; ``1 + b``: in object b; ``1 + M + b``: on top of b (b = M is the floor); ``2 + 2M``:
    unsupported. Containment wins over support; among several supports the first is taken.
    """
    k, m = modes.shape
    label = np.full((k, m), 2 + 2 * m, dtype=int)
    any_on = on_top.any(axis=-1)
    label = np.where(any_on, 1 + m + np.argmax(on_top, axis=-1), label)
    any_in = is_in.any(axis=-1)
    label = np.where(any_in, 1 + np.argmax(is_in, axis=-1), label)
    return np.where(is_held(modes), 0, label)


def _label_name(label: int, object_ids) -> tuple[str, str | None]:
    m = len(object_ids)
    names = list(object_ids) + ["floor"]
    if label == 0:
        return "held", None
    if label <= m:
        return "isIn", names[label - 1]
    if label <= 2 * m + 1:
        return "isOnTop", names[label - 1 - m]
    return "none", None


def pose_stats(poses: np.ndarray, w: np.ndarray):
    """Weighted statistics of particle poses ``(K, M, 7)`` with normalised weights ``(K,)``.

    Returns mean positions ``(M, 3)``, position covariances ``(M, 3, 3)``, chordal L2 mean
    orientations ``(M, 4)`` (x, y, z, w; the principal eigenvector of ``sum_k w_k q_k q_k^T``, as
    scipy's ``Rotation.mean``) and angular spreads ``(M,)`` (rad, weighted RMS angle to the mean).
    With all the weight on one particle, its poses are returned exactly, with zero spread.
    """
    k, m = poses.shape[:2]
    if k == 1 or np.max(w) >= 1.0:
        best = int(np.argmax(w))
        return poses[best, :, :3].copy(), np.zeros((m, 3, 3)), poses[best, :, 3:].copy(), np.zeros(m)
    means = np.einsum("k,kmi->mi", w, poses[..., :3])
    dev = poses[..., :3] - means[None]
    dev = dev.transpose(1, 0, 2)  # (M, K, 3)
    covs = (dev.transpose(0, 2, 1) * w) @ dev
    q = poses[..., 3:].transpose(1, 0, 2)  # (M, K, 4)
    _, vecs = np.linalg.eigh((q.transpose(0, 2, 1) * w) @ q)  # sum_k w_k q_k q_k^T, (M, 4, 4)
    quats = vecs[..., -1]
    quats = np.where(quats[:, 3:4] < 0, -quats, quats)
    angs = np.sqrt(w @ quat_angle(poses[..., 3:], quats[None]) ** 2)
    return means, covs, quats, angs


def _group_stats(positions: np.ndarray, weights: np.ndarray, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean ``(3,)`` and covariance ``(3, 3)`` of the ``positions (K, 3)`` of the particles
    in ``members (K,)`` bool, their ``weights (K,)`` renormalised within the group."""
    x, w = positions[members], weights[members]
    w = w / w.sum()
    mean = w @ x
    dev = x - mean
    return mean, (dev.T * w) @ dev


REPORTED_PARAMETERS = {"friction": 0, "rolling_friction": 1, "restitution": 3, "mass": 4}
"""The physical parameters an object's belief reports (name -> column of the ``(K, M, 5)`` arrays)."""


def parameter_posterior(params: np.ndarray, weights: np.ndarray, m: int) -> dict[str, tuple[float, float]]:
    """Weighted mean and standard deviation of object ``m``'s :data:`REPORTED_PARAMETERS` over the
    particles: ``params (K, M, 5)``, ``weights (K,)`` normalised."""
    out = {}
    for name, col in REPORTED_PARAMETERS.items():
        x = params[:, m, col]
        mu = float(weights @ x)
        out[name] = (mu, float(np.sqrt(max(weights @ (x - mu) ** 2, 0.0))))
    return out


def compute_belief(t: float, object_ids, known: np.ndarray, perceived: np.ndarray, poses: np.ndarray,
                   weights: np.ndarray, modes: np.ndarray, on_top: np.ndarray, is_in: np.ndarray,
                   events: list[EventRecord], ess: float, static: np.ndarray, min_p: float = 0.02,
                   keep_particles: bool = True, cov_floor: float = 0.0, dof: float = math.inf,
                   params: np.ndarray | None = None) -> Belief:
    """Assemble a :class:`Belief` from particle arrays (K particles, M objects).

    ``poses (K, M, 7)``, ``weights (K,)`` normalised, ``modes (K, M)``, ``on_top (K, M, M+1)``,
    ``is_in (K, M, M)``; ``known``, ``perceived``, ``static`` ``(M,)`` bool. Unknown objects are left
    out; static objects get their fixed pose and no hypotheses. ``cov_floor`` (m^2) is added to the
    diagonal of the position covariances of dynamic objects, whose positions are then Student-t with
    ``dof`` degrees of freedom (``inf``: Gaussian). A hypothesis is a support label
    (:func:`support_labels`); the headline position and covariance are those of the heaviest one (see
    :class:`ObjectBelief`), the first of ``hypotheses``. ``params (K, M, 5)``: the particles'
    physical parameters, whose posterior each dynamic object reports (None: not reported).
    """
    object_ids = tuple(object_ids)
    k, m_count = modes.shape
    labels = support_labels(modes, on_top, is_in)
    # per object and label: weight, number of particles and weighted position sum, in one pass
    n_labels = 3 + 2 * m_count
    flat = (np.arange(m_count)[None, :] * n_labels + labels).ravel()
    wk = np.broadcast_to(weights[:, None], (k, m_count)).ravel()
    size = m_count * n_labels
    p_lab = np.bincount(flat, weights=wk, minlength=size).reshape(m_count, n_labels)
    n_lab = np.bincount(flat, minlength=size).reshape(m_count, n_labels)
    pos_lab = np.stack([np.bincount(flat, weights=wk * poses[..., d].ravel(), minlength=size)
                        for d in range(3)], axis=-1).reshape(m_count, n_labels, 3)
    p_held_all = weights @ is_held(modes)
    objects = {}
    means, covs, quats, angs = pose_stats(poses, weights)
    eye = np.eye(3)
    for m, oid in enumerate(object_ids):
        if not known[m]:
            continue
        mean, cov, q, ang = means[m], covs[m], quats[m], float(angs[m])
        top = int(np.argmax(p_lab[m]))
        if static[m] or n_lab[m, top] == k:  # one mode: the headline is the mean
            pos, pos_cov = mean, cov
        else:
            pos, pos_cov = _group_stats(poses[:, m, :3], weights, labels[:, m] == top)
        if not static[m] and cov_floor > 0:
            cov, pos_cov = cov + cov_floor * eye, pos_cov + cov_floor * eye
        p_held = float(p_held_all[m])
        p_plausible = 1.0 - p_held if perceived[m] else 1.0
        hyps = []
        if not static[m]:
            for lab in np.flatnonzero((n_lab[m] > 0) & (p_lab[m] >= min_p)).tolist():
                p = float(p_lab[m, lab])
                rel, sup = _label_name(lab, object_ids)
                hyps.append(Hypothesis(p, rel, sup, pos_lab[m, lab] / p if p > 0 else pos_lab[m, lab]))
            hyps.sort(key=lambda h: -h.p)
        objects[oid] = ObjectBelief(pos, q, pos_cov, ang, bool(perceived[m]), p_plausible, p_held, tuple(hyps),
                                    mean, cov, position_dof=math.inf if static[m] else float(dof),
                                    parameters=None if static[m] or params is None
                                    else parameter_posterior(params, weights, m))
    p_on = np.tensordot(weights, on_top.astype(float), axes=1)
    p_in = np.tensordot(weights, is_in.astype(float), axes=1) if is_in.any() else np.zeros(is_in.shape[1:])
    relations = relation_list(None, None, object_ids, p_on, p_in, threshold=min_p)
    return Belief(t, objects, relations, events, ess, object_ids,
                  poses.copy() if keep_particles else None, weights.copy() if keep_particles else None)


class SpeedVariance:
    """Adds ``(time * speed)**2`` to the position variance of every dynamic object not detected in an
    update, ``speed`` (m/s) being how far its headline position moved since the previous update
    (:attr:`~estimator.config.NoiseConfig.covariance_speed_time` is ``time``, s; 0 is off). It
    remembers the headline positions from one update to the next."""

    def __init__(self, time: float, dynamic: np.ndarray):
        self.time, self.dynamic = float(time), np.asarray(dynamic, bool)
        self._headline: np.ndarray | None = None  # (M, 3) the last update's headline positions

    def __call__(self, belief: "Belief", detected: np.ndarray, dt: float) -> "Belief":
        """``belief`` of an update ``dt`` (s) after the previous one, ``detected (M,)`` in it."""
        if self.time <= 0:  # off (the fitted default): nothing to remember either
            return belief
        now = headline_positions(belief)
        prev, self._headline = self._headline, now
        if prev is None or dt <= 0:
            return belief
        moved = np.linalg.norm(now - prev, axis=1)
        ok = np.isfinite(moved) & self.dynamic & ~np.asarray(detected, bool)
        return with_added_variance(belief, (self.time * np.where(ok, moved, 0.0) / dt) ** 2)
