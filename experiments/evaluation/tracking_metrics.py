"""Tracking metrics of one trial: what happens when a hidden object comes back, and the normalised
estimation error squared (NEES) while objects are seen and hidden. Pure functions on arrays.

Units: metres, seconds. T reasoning steps, F perception frames, D scored (dynamic) objects.

* **re-appearance**: a detection of an object in a frame after at least ``min_gap`` seconds (0.3 s,
  longer than a dropout flicker) without a detection of it; objects never detected before are not
  counted. The method's *prior* is its estimate at its last reasoning step strictly before that
  frame.
* **error at re-appearance**: distance (m) between that prior position and the true position at the
  frame: where the method expected the object when it came back.
* **gate rate**: fraction of re-appearances whose detection falls inside the ``gate_probability``
  (99 %) chi-square(3) gate of the prior, ``S = prior covariance + R``, ``R = std^2 I`` with the
  detection's ``position_std`` or ``measurement_std``: how often a Kalman tracker primed with that
  prior would have accepted the returning detection instead of rejecting it or re-initialising.
  For the Kalman tracker's own methods it is what the tracker did (it predicts to the detection's
  time with its velocity, which the estimator's prior, up to one reasoning period old, does not).
* **NEES**: ``e' (P + floor^2 I)^-1 e`` of the position (``floor`` 1 mm keeps point estimates
  invertible), median and mean over the (step, object) samples where the object is seen / hidden; a
  consistent estimate has the chi-square(3) median, 2.37, and mean, 3. Over R independent trials,
  the average of the trials' means lies in ``[chi2.ppf(0.025, 3R), chi2.ppf(0.975, 3R)] / R`` at 95 %
  when each trial's samples are one chi-square(3) draw repeated (fully correlated in time); less
  correlated samples make the true band narrower, so this band is the lenient one
  (:func:`nees_band`).
"""
from __future__ import annotations

import math

import numpy as np

from estimator.belief import chi2_quantile

REAPPEAR_GAP = 0.3
"""A detection after at least this many seconds without one is a re-appearance (s)."""
NEES_FLOOR_STD = 0.001
"""Standard deviation (m) added isotropically to a covariance before computing a NEES."""


def reappearances(det_t: np.ndarray, detected: np.ndarray, min_gap: float = REAPPEAR_GAP) -> list[tuple[int, int]]:
    """``(frame index, object index)`` of every re-appearance. ``det_t (F,)`` frame times (s),
    ``detected (F, D)`` bool."""
    out = []
    det_t = np.asarray(det_t, float)
    for k in range(detected.shape[1]):
        idx = np.flatnonzero(detected[:, k])
        for prev, cur in zip(idx[:-1], idx[1:]):
            if det_t[cur] - det_t[prev] >= min_gap - 1e-9:
                out.append((int(cur), k))
    return out


def reappearance_scores(step_t: np.ndarray, est: np.ndarray, cov: np.ndarray, det_t: np.ndarray,
                        det_pos: np.ndarray, det_std: np.ndarray, true_pos: np.ndarray,
                        measurement_std: float = 0.01, gate_probability: float = 0.99,
                        min_gap: float = REAPPEAR_GAP, accepted: np.ndarray | None = None) -> dict[str, float]:
    """Error at re-appearance and gate rate (see the module docstring).

    Args:
        step_t: ``(T,)`` times of the method's reasoning steps (s).
        est, cov: ``(T, D, 3)`` positions (NaN: unknown to the method) and ``(T, D, 3, 3)`` covariances.
        det_t: ``(F,)`` frame times (s); ``det_pos (F, D, 3)`` detected positions, NaN where not
            detected; ``det_std (F, D)`` each detection's ``position_std`` (NaN: none given).
        true_pos: ``(F, D, 3)`` true positions at the frame times.
        accepted: ``(F, D)`` bool, what a Kalman tracker did with each detection (accepted in its
            gate, after predicting to the frame's time); when given, it decides the gate rate
            instead of the prior's covariance.

    Returns ``n_reappear``, ``err_reappear_median`` (m) and ``gate_rate_reappear``; an estimate
    unknown (NaN) at re-appearance counts as outside the gate and is left out of the error.
    """
    step_t = np.asarray(step_t, float)
    detected = np.isfinite(det_pos).all(axis=-1)
    errors, inside = [], []
    gate = chi2_quantile(gate_probability, 3)
    for f, k in reappearances(det_t, detected, min_gap):
        i = int(np.searchsorted(step_t, det_t[f] - 1e-9, side="left")) - 1  # last step strictly before
        if i < 0:
            continue
        mean, c = est[i, k], cov[i, k]
        if not np.all(np.isfinite(mean)):
            inside.append(False if accepted is None else bool(accepted[f, k]))
            continue
        std = det_std[f, k] if np.isfinite(det_std[f, k]) else measurement_std
        y = det_pos[f, k] - mean
        if accepted is not None:
            inside.append(bool(accepted[f, k]))
        else:
            inside.append(bool(y @ np.linalg.solve(c + std ** 2 * np.eye(3), y) <= gate))
        errors.append(float(np.linalg.norm(mean - true_pos[f, k])))
    return {"n_reappear": len(inside),
            "err_reappear_median": float(np.median(errors)) if errors else math.nan,
            "gate_rate_reappear": float(np.mean(inside)) if inside else math.nan}


def nees_scores(est: np.ndarray, cov: np.ndarray, tru: np.ndarray, visible: np.ndarray,
                floor_std: float = NEES_FLOOR_STD) -> dict[str, float]:
    """Median position NEES where the object is seen and where it is hidden. ``est``, ``tru``
    ``(T, D, 3)`` m (NaN estimates are left out), ``cov (T, D, 3, 3)`` m^2, ``visible (T, D)`` bool."""
    ok = np.isfinite(est).all(axis=-1)
    e = np.where(ok[..., None], tru - np.where(ok[..., None], est, 0.0), 0.0)
    c = np.asarray(cov, float) + floor_std ** 2 * np.eye(3)
    m2 = np.sum(e * np.linalg.solve(c, e[..., None])[..., 0], axis=-1)
    out = {}
    for name, mask in (("seen", ok & visible), ("hidden", ok & ~visible)):
        v = m2[mask]
        out[f"nees_{name}_median"] = float(np.median(v)) if v.size else math.nan
        out[f"nees_{name}_mean"] = float(np.mean(v)) if v.size else math.nan
    return out


def nees_band(trials: int, dof: int = 3, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the average over ``trials`` of per-trial mean NEES (see the
    module docstring): ``chi2.ppf((1 -+ probability) / 2, dof * trials) / trials``."""
    a = (1.0 - probability) / 2.0
    return (float(chi2_quantile(a, dof * trials) / trials), float(chi2_quantile(1.0 - a, dof * trials) / trials))
