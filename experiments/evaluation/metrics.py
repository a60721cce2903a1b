"""Metrics of one trial: pure functions on arrays and plain dicts.

Units: metres, seconds. Probabilities in [0, 1]. Every function documents its inputs; none keeps
state or draws random numbers. Conventions:

* **position error**: Euclidean distance (m) between the estimate's consensus position and the true
  position. *Hidden* means the ground truth says the object is not visible to the camera.
* **support**: where an object is, ``(relation, support)`` with ``relation`` in isIn, isOnTop,
  held, none. The truth's support is derived from the true relations by priority isIn X > isOnTop X
  > held > none; when several supports tie at the winning level, any of them counts as correct.
* **early / late hidden**: a hidden sample is *early* when its object was last visible (at a scored
  step) at most :data:`EARLY_HIDDEN` seconds before, *late* otherwise; an object hidden from the
  first step counts from that step. Coverage, NLL and the median error are also reported over each.
* **success** (at the end of a trial): error < 5 cm *and* the estimate's top hypothesis is a true
  support.
* **events**: greedy one-to-one matching of estimated to true events with the same action and
  subject within a window (0.5 s), closest pairs first. Latency = estimated t - true t. Scored over
  all actions and per action (Pick, Place, Release, Push: :data:`ACTIONS`).
  Empty cases: no true and no estimated events: precision, recall and F1 are undefined (NaN); no
  estimates but some truth: precision NaN, recall 0, F1 0; estimates but no truth: precision 0,
  recall NaN, F1 0.
* **calibration**: the Gaussian N(mean, cov + floor^2 I) (floor 5 mm) is the estimate's predictive
  distribution of the position (a point estimate gets the floor alone); NLL is its negative log
  density at the true position (nats); an x % region is the ellipsoid whose squared Mahalanobis
  radius is the chi-square(3) x % quantile. Probabilities are scored against binary truths with the
  Brier score and the expected calibration error over equal-width bins.
* **physically plausible** (the truth of P(plausible)): an object is plausible when it is *not held*
  by the hand; a held object is moved by an agent, not by physics, which is exactly what the
  estimator's "not plausible" means (``p_plausible = 1 - p_held`` for a perceived object).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaln

from actions.modes import EVENT_NAMES
from estimator.belief import region_radius_sq

SUCCESS_DISTANCE = 0.05
"""Success needs the final position error below this (m)."""
EVENT_WINDOW = 0.5
"""Estimated and true events match within this many seconds."""
EARLY_HIDDEN = 1.0
"""Hidden samples at most this many seconds after their object was last visible are *early*: the
first second of an occlusion, while the belief's spread is still growing from what it was when the
object vanished."""
COV_FLOOR_STD = 0.005
"""Standard deviation (m) added isotropically to every predicted covariance."""
N_BINS = 10
"""Equal-width probability bins of the reliability diagrams and the ECE."""
ACTIONS: tuple[str, ...] = tuple(EVENT_NAMES.values())
"""The actions events are scored for one by one: Pick, Place, Release, Push."""


# --------------------------------------------------------------------------------------------------
# positions


def position_errors(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distances (m) between estimated and true positions, ``(..., 3)`` each -> ``(...)``. NaN where
    the estimate is NaN (object unknown to the method)."""
    return np.linalg.norm(np.asarray(estimate, float) - np.asarray(truth, float), axis=-1)


def error_quantiles(errors: np.ndarray, mask: np.ndarray | None = None) -> dict[str, float]:
    """Median and 90th percentile (m) of ``errors`` (any shape) where ``mask`` (same shape) is true
    and the error is finite. ``{"median": nan, "p90": nan, "n": 0}`` when nothing is selected."""
    e = np.asarray(errors, float)
    sel = np.isfinite(e) if mask is None else (np.asarray(mask, bool) & np.isfinite(e))
    v = e[sel]
    if v.size == 0:
        return {"median": math.nan, "p90": math.nan, "n": 0}
    return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)), "n": int(v.size)}


def hidden_durations(times: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """How long (s) each object has been hidden at each step: ``times (T,)`` s, increasing;
    ``visible (T, D)`` bool. Returns ``(T, D)`` float: 0 where visible, else the time since the
    object's last visible step (since the first step for an object hidden from the start)."""
    t = np.asarray(times, float)
    vis = np.asarray(visible, bool)
    if vis.ndim != 2 or t.shape != vis.shape[:1]:
        raise ValueError(f"hidden_durations: times {t.shape} and visible {vis.shape} do not agree")
    if t.size == 0:
        return np.zeros(vis.shape)
    last = np.maximum.accumulate(np.where(vis, t[:, None], -np.inf), axis=0)
    return np.where(vis, 0.0, t[:, None] - np.where(np.isfinite(last), last, t[0]))


def truth_supports(relations: list[dict], subject: str, held: bool) -> set[tuple[str, str | None]]:
    """The true support(s) of ``subject`` from one truth row's ``relations``
    (``[{"subject", "predicate", "object", ...}]``) and whether it is ``held``: every isIn object if
    any, else every isOnTop object if any, else ``{("held", None)}`` or ``{("none", None)}``."""
    for predicate in ("isIn", "isOnTop"):
        found = {(predicate, r["object"]) for r in relations
                 if r["subject"] == subject and r["predicate"] == predicate and r.get("p", 1.0) > 0.5}
        if found:
            return found
    return {("held", None)} if held else {("none", None)}


def success(error: float, top: tuple[str, str | None], supports: set[tuple[str, str | None]],
            distance: float = SUCCESS_DISTANCE) -> bool:
    """Final success of one object: ``error`` (m) < ``distance`` and the estimate's top hypothesis
    ``top = (relation, support)`` is in the true ``supports``."""
    return bool(np.isfinite(error) and error < distance and tuple(top) in supports)


# --------------------------------------------------------------------------------------------------
# binary facts


def binary_scores(predicted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Accuracy, precision, recall and F1 of boolean ``predicted`` against boolean ``truth`` (same
    shape, any). Empty-set conventions as for events: precision NaN without predictions, recall NaN
    without positives in the truth, F1 NaN when both are empty and 0 when nothing matches."""
    p = np.asarray(predicted, bool).ravel()
    y = np.asarray(truth, bool).ravel()
    if p.shape != y.shape:
        raise ValueError(f"shapes differ: {p.shape} vs {y.shape}")
    tp = int(np.sum(p & y))
    out = precision_recall_f1(tp, int(p.sum()), int(y.sum()))
    out["accuracy"] = float(np.mean(p == y)) if p.size else math.nan
    return out


def precision_recall_f1(tp: int, n_est: int, n_true: int) -> dict[str, float]:
    """``{"precision", "recall", "f1"}`` of ``tp`` true positives among ``n_est`` estimates and
    ``n_true`` true cases (NaN where undefined: see the module docstring's empty cases)."""
    precision = tp / n_est if n_est else math.nan
    recall = tp / n_true if n_true else math.nan
    if n_est == 0 and n_true == 0:
        f1 = math.nan
    elif tp == 0:
        f1 = 0.0
    else:
        f1 = 2 * precision * recall / (precision + recall)
    return {"precision": precision, "recall": recall, "f1": f1}


# --------------------------------------------------------------------------------------------------
# events


def match_events(estimated: list[dict], truth: list[dict], window: float = EVENT_WINDOW
                 ) -> list[tuple[int, int]]:
    """Greedy one-to-one matching of events ``{"t", "action", "subject"}``: among all (estimated,
    true) pairs with the same action and subject and ``|dt| <= window`` (s), take the closest pair,
    remove both, repeat (ties: earlier true event, then earlier estimate). Returns ``(i_est, i_true)``
    index pairs."""
    pairs = []
    for i, e in enumerate(estimated):
        for j, g in enumerate(truth):
            if e["action"] == g["action"] and e["subject"] == g["subject"]:
                dt = abs(float(e["t"]) - float(g["t"]))
                if dt <= window + 1e-9:
                    pairs.append((dt, j, i))
    pairs.sort()
    used_e, used_t, out = set(), set(), []
    for _dt, j, i in pairs:
        if i in used_e or j in used_t:
            continue
        used_e.add(i)
        used_t.add(j)
        out.append((i, j))
    return sorted(out)


def event_scores(estimated: list[dict], truth: list[dict], window: float = EVENT_WINDOW,
                 actions: tuple[str, ...] | None = None) -> dict[str, float]:
    """Precision, recall, F1 and latency of ``estimated`` events against ``truth`` (lists of
    ``{"t", "action", "subject"}``, t in s). ``actions`` restricts both lists to those actions.
    Returns ``precision``, ``recall``, ``f1``, ``latency_median`` (s, NaN without matches),
    ``latency_mean``, ``n_true``, ``n_est``, ``n_matched``."""
    if actions is not None:
        estimated = [e for e in estimated if e["action"] in actions]
        truth = [g for g in truth if g["action"] in actions]
    matches = match_events(estimated, truth, window)
    out = precision_recall_f1(len(matches), len(estimated), len(truth))
    lat = np.array([float(estimated[i]["t"]) - float(truth[j]["t"]) for i, j in matches])
    out["latency_median"] = float(np.median(lat)) if lat.size else math.nan
    out["latency_mean"] = float(np.mean(lat)) if lat.size else math.nan
    out.update(n_true=len(truth), n_est=len(estimated), n_matched=len(matches))
    return out


def event_scores_by_action(estimated: list[dict], truth: list[dict], window: float = EVENT_WINDOW,
                           actions: tuple[str, ...] = ACTIONS) -> dict[str, dict[str, float]]:
    """:func:`event_scores` of each action alone: ``{action: scores}`` for every action of
    ``actions`` (an action neither list has gets NaN precision, recall and F1 and zero counts)."""
    return {a: event_scores(estimated, truth, window, actions=(a,)) for a in actions}


# --------------------------------------------------------------------------------------------------
# calibration


def _floored(cov: np.ndarray, floor_std: float) -> np.ndarray:
    cov = np.asarray(cov, float)
    return cov + (floor_std ** 2) * np.eye(cov.shape[-1])


def mahalanobis_sq(mean: np.ndarray, cov: np.ndarray, x: np.ndarray, floor_std: float = COV_FLOOR_STD
                   ) -> np.ndarray:
    """Squared Mahalanobis distance of ``x`` from N(``mean``, ``cov`` + floor^2 I). ``mean``, ``x``:
    ``(..., d)`` m; ``cov``: ``(..., d, d)`` m^2. Returns ``(...)``."""
    d = np.asarray(x, float) - np.asarray(mean, float)
    c = _floored(cov, floor_std)
    sol = np.linalg.solve(c, d[..., None])[..., 0]
    return np.sum(d * sol, axis=-1)


def gaussian_nll(mean: np.ndarray, cov: np.ndarray, x: np.ndarray, floor_std: float = COV_FLOOR_STD,
                 dof=math.inf) -> np.ndarray:
    """Negative log density (nats, with positions in m) of ``x`` under N(``mean``, ``cov`` +
    floor^2 I); shapes as :func:`mahalanobis_sq`. Returns ``(...)``. With finite ``dof`` (> 2, a
    scalar or ``(...)``, ``inf`` entries Gaussian), under the multivariate Student-t of that
    covariance and those degrees of freedom instead (:func:`estimator.belief.region_radius_sq`)."""
    c = _floored(cov, floor_std)
    dim = c.shape[-1]
    _sign, logdet = np.linalg.slogdet(c)
    m2 = mahalanobis_sq(mean, cov, x, floor_std)
    gauss = 0.5 * (m2 + logdet + dim * math.log(2 * math.pi))
    dof = np.broadcast_to(np.asarray(dof, float), np.shape(gauss))
    if np.all(np.isinf(dof)):
        return gauss
    nu = np.where(np.isfinite(dof), dof, 3.0)
    # scale matrix S = cov (nu - 2) / nu: x^T S^-1 x = m2 nu / (nu - 2), log|S| = logdet + d log((nu - 2) / nu)
    shrink = (nu - 2.0) / nu
    t = (gammaln(nu / 2) - gammaln((nu + dim) / 2) + 0.5 * dim * np.log(nu * math.pi)
         + 0.5 * (logdet + dim * np.log(shrink)) + 0.5 * (nu + dim) * np.log1p(m2 / (shrink * nu)))
    return np.where(np.isfinite(dof), t, gauss)


def in_regions(m2: np.ndarray, levels=(0.5, 0.9), dof=math.inf, dim: int = 3) -> np.ndarray:
    """Whether each squared Mahalanobis distance ``m2 (N,)`` (over the covariance) lies inside the
    ``level`` region of its distribution, per level: ``(N, L)`` bool. ``dof`` (a scalar or ``(N,)``;
    ``inf``: Gaussian) as in :func:`estimator.belief.region_radius_sq`."""
    m2 = np.asarray(m2, float)
    return np.stack([m2 <= region_radius_sq(lv, dof, dim) for lv in levels], axis=-1)


def coverage(mean: np.ndarray, cov: np.ndarray, x: np.ndarray, levels=(0.5, 0.9),
             floor_std: float = COV_FLOOR_STD, dof=math.inf) -> dict[float, float]:
    """Fraction of the rows of ``x`` ``(N, d)`` inside the ``level`` credible ellipsoid of
    N(``mean (N, d)``, ``cov (N, d, d)`` + floor^2 I), per level; with finite ``dof`` (a scalar or
    ``(N,)``), of the Student-t of that covariance (:func:`in_regions`). A calibrated estimate covers
    about ``level``. NaN for empty input."""
    m2 = mahalanobis_sq(mean, cov, x, floor_std)
    if m2.size == 0:
        return {lv: math.nan for lv in levels}
    inside = in_regions(m2, levels, dof, np.asarray(x).shape[-1])
    return {lv: float(np.mean(inside[:, j])) for j, lv in enumerate(levels)}


def brier_score(p: np.ndarray, y: np.ndarray) -> float:
    """Mean squared difference between probabilities ``p`` and binary outcomes ``y`` (same shape);
    0 is perfect, NaN for empty input."""
    p = np.asarray(p, float).ravel()
    y = np.asarray(y, float).ravel()
    return float(np.mean((p - y) ** 2)) if p.size else math.nan


def reliability_bins(p: np.ndarray, y: np.ndarray, n_bins: int = N_BINS) -> dict[str, list]:
    """Counts of a reliability diagram: probabilities ``p`` in ``n_bins`` equal-width bins over
    [0, 1] (1.0 falls in the last). Returns ``{"n": counts, "p_sum": sums of p, "y_sum": sums of
    y}`` per bin, which add up across trials."""
    p = np.clip(np.asarray(p, float).ravel(), 0.0, 1.0)
    y = np.asarray(y, float).ravel()
    idx = np.minimum((p * n_bins).astype(int), n_bins - 1)
    return {"n": np.bincount(idx, minlength=n_bins).astype(int).tolist(),
            "p_sum": np.bincount(idx, weights=p, minlength=n_bins).tolist(),
            "y_sum": np.bincount(idx, weights=y, minlength=n_bins).tolist()}


def ece_from_bins(bins: dict[str, list]) -> float:
    """Expected calibration error from :func:`reliability_bins` counts: the count-weighted mean of
    |mean p - frequency of y| over non-empty bins. NaN when empty."""
    n = np.asarray(bins["n"], float)
    total = n.sum()
    if total == 0:
        return math.nan
    nz = n > 0
    gap = np.abs(np.asarray(bins["p_sum"])[nz] - np.asarray(bins["y_sum"])[nz]) / n[nz]
    return float(np.sum(n[nz] * gap) / total)


def expected_calibration_error(p: np.ndarray, y: np.ndarray, n_bins: int = N_BINS) -> float:
    """ECE of probabilities ``p`` against binary ``y`` over ``n_bins`` equal-width bins."""
    return ece_from_bins(reliability_bins(p, y, n_bins))


def merge_bins(bins: list[dict[str, list]]) -> dict[str, list]:
    """Sum reliability counts of several trials (same number of bins)."""
    out = None
    for b in bins:
        if out is None:
            out = {k: np.asarray(v, float) for k, v in b.items()}
        else:
            for k in out:
                out[k] = out[k] + np.asarray(b[k], float)
    if out is None:
        return {"n": [0] * N_BINS, "p_sum": [0.0] * N_BINS, "y_sum": [0.0] * N_BINS}
    return {k: v.tolist() for k, v in out.items()}
