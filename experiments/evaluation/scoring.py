"""Scoring a method's run against the ground truth: one flat dict of metrics
(:mod:`experiments.evaluation.metrics`, :mod:`experiments.evaluation.tracking_metrics`)."""
from __future__ import annotations

import math

import numpy as np

from experiments.evaluation import metrics as M
from experiments.evaluation.method_steps import MethodRun

LOOSE_EVENT_WINDOW = 1.5
"""A second, looser event-matching window (s): the paper's reasoner only notices that a vanished
object was released after its 0.7 s perception timeout, later than the 0.5 s window."""

# --------------------------------------------------------------------------------------------------
# scoring a run


def dynamic_objects(scene) -> list[int]:
    """Indices of the scene's dynamic (non-static) objects, the ones scored."""
    return [i for i, o in enumerate(scene.objects) if not o.static]


def _truth_rows_at(truth: list[dict], times: list[float]) -> list[dict]:
    """The truth row at (or, failing an exact match, last before) each time."""
    tt = np.array([r["t"] for r in truth])
    out = []
    for t in times:
        j = int(np.searchsorted(tt, t + 1e-6, side="right")) - 1
        out.append(truth[max(j, 0)])
    return out


def position_arrays(scene, truth: list[dict], steps) -> tuple[np.ndarray, ...]:
    """The positions a run's ``steps`` (:class:`~experiments.evaluation.method_steps.StepEstimate`) give
    for the scene's dynamic objects, beside the truth at each step: ``est (T, D, 3)`` m (NaN where
    unknown), ``cov (T, D, 3, 3)`` m^2, ``dof (T, D)`` (inf: Gaussian), ``tru (T, D, 3)`` m,
    ``vis (T, D)`` and ``held (T, D)`` bool, and the truth rows ``(T,)`` themselves."""
    ids = list(scene.object_ids)
    dyn = dynamic_objects(scene)
    dyn_ids = [ids[i] for i in dyn]
    T, D = len(steps), len(dyn)
    rows = _truth_rows_at(truth, [s.t for s in steps])
    est = np.array([s.positions[dyn] for s in steps]).reshape(T, D, 3)
    cov = np.array([s.covariances[dyn] for s in steps]).reshape(T, D, 3, 3)
    dof = np.array([np.full(D, np.inf) if s.dof is None else np.asarray(s.dof, float)[dyn]
                    for s in steps]).reshape(T, D)
    tru = np.array([[r["objects"][o]["position"] for o in dyn_ids] for r in rows]).reshape(T, D, 3)
    vis = np.array([[r["objects"][o]["visible"] for o in dyn_ids] for r in rows], bool).reshape(T, D)
    held = np.array([[r["objects"][o]["held"] for o in dyn_ids] for r in rows], bool).reshape(T, D)
    return est, cov, dof, tru, vis, held, rows


def score_run(scene, truth: list[dict], true_events: list[dict], run: MethodRun, frames=None) -> dict:
    """Metrics of one method run against the ground truth (a flat dict plus ``"reliability"``).

    Args:
        scene: the scene the method ran on (object order of the arrays).
        truth: truth rows (one per camera frame) of :class:`~experiments.simulation.simulator.SimulationResult`.
        true_events: the true events ``[{"t", "action", "subject"}]``.
        run: the method's steps and events.
        frames: the perception frames the method ran on; when given, the re-appearance and NEES
            metrics of :mod:`experiments.evaluation.tracking_metrics` are added.

    Objects scored: the dynamic (non-static) objects. Samples: every (reasoning step, object).
    """
    ids = list(scene.object_ids)
    dyn = dynamic_objects(scene)
    dyn_ids = [ids[i] for i in dyn]
    names = ids + ["floor"]
    steps = run.steps
    T, D, Mo = len(steps), len(dyn), len(ids)
    est, cov, dof, tru, vis, held, rows = position_arrays(scene, truth, steps)
    p_pl = np.array([s.p_plausible[dyn] for s in steps]).reshape(T, D)

    # relations as (T, D, Mo + 1) / (T, D, Mo) arrays of probabilities and truths
    col = {n: j for j, n in enumerate(names)}
    sub = {o: k for k, o in enumerate(dyn_ids)}

    def fill(rel_dicts, predicate, width):
        a = np.zeros((T, D, width))
        for t_i, rels in enumerate(rel_dicts):
            for (s, p, o), prob in rels.items():
                if p == predicate and s in sub and o in col and col[o] < width:
                    a[t_i, sub[s], col[o]] = prob
        return a

    def truth_dict(r):
        return {(x["subject"], x["predicate"], x["object"]): float(x.get("p", 1.0)) for x in r["relations"]}

    est_rels = [s.relations for s in steps]
    tru_rels = [truth_dict(r) for r in rows]
    pair_on = np.ones((D, Mo + 1), bool)
    pair_in = np.ones((D, Mo), bool)
    for k, i in enumerate(dyn):
        pair_on[k, i] = pair_in[k, i] = False
    p_on, y_on = fill(est_rels, "isOnTop", Mo + 1), fill(tru_rels, "isOnTop", Mo + 1) > 0.5
    p_in, y_in = fill(est_rels, "isIn", Mo), fill(tru_rels, "isIn", Mo) > 0.5
    p_on, y_on = p_on[:, pair_on], y_on[:, pair_on]
    p_in, y_in = p_in[:, pair_in], y_in[:, pair_in]

    out: dict = {"n_steps": T, "n_objects": D}
    err = M.position_errors(est, tru)
    hidden = ~vis
    q_all, q_hid = M.error_quantiles(err), M.error_quantiles(err, hidden)
    out.update(n_hidden=q_hid["n"], err_median=q_all["median"], err_p90=q_all["p90"],
               err_hidden_median=q_hid["median"], err_hidden_p90=q_hid["p90"])
    # hidden samples in the first second of their occlusion, and after it
    hidden_s = M.hidden_durations(np.array([s.t for s in steps]), vis)
    early = hidden & (hidden_s <= M.EARLY_HIDDEN)
    for suffix, mask in (("_early", early), ("_late", hidden & ~early)):
        q = M.error_quantiles(err, mask)
        out[f"n_hidden{suffix}"], out[f"err_hidden{suffix}_median"] = q["n"], q["median"]
    # the end of the run
    if T:
        end_err = err[-1]
        sup = [M.truth_supports(rows[-1]["relations"], o, bool(held[-1, k])) for k, o in enumerate(dyn_ids)]
        ok = np.array([M.success(end_err[k], steps[-1].top[i], sup[k]) for k, i in enumerate(dyn)])
        ever_hidden = hidden.any(axis=0)
        out.update(err_end_mean=float(np.mean(end_err)), err_end_max=float(np.max(end_err)),
                   success_end=float(np.mean(ok)),
                   success_end_hidden=float(np.mean(ok[ever_hidden])) if ever_hidden.any() else math.nan)
    else:
        out.update(err_end_mean=math.nan, err_end_max=math.nan, success_end=math.nan,
                   success_end_hidden=math.nan)
    # relations over time
    for name, p, y in (("ontop", p_on, y_on), ("isin", p_in, y_in)):
        sc = M.binary_scores(p > 0.5, y)
        out[f"{name}_acc"], out[f"{name}_f1"] = sc["accuracy"], sc["f1"]
    # events
    ev = M.event_scores(run.events, true_events)
    out.update(event_precision=ev["precision"], event_recall=ev["recall"], event_f1=ev["f1"],
               event_latency=ev["latency_median"], events_true=ev["n_true"], events_est=ev["n_est"],
               events_matched=ev["n_matched"])
    loose = M.event_scores(run.events, true_events, window=LOOSE_EVENT_WINDOW)
    out.update(event_f1_loose=loose["f1"], event_latency_loose=loose["latency_median"])
    for action, sc in M.event_scores_by_action(run.events, true_events).items():
        a = action.lower()
        out.update({f"{a}_precision": sc["precision"], f"{a}_recall": sc["recall"], f"{a}_f1": sc["f1"],
                    f"{a}_latency": sc["latency_median"], f"{a}_true": sc["n_true"], f"{a}_est": sc["n_est"],
                    f"{a}_matched": sc["n_matched"]})
    # calibration of the position
    # (each position with its own distribution: dof inf for Gaussian ones)
    ok = np.isfinite(est).all(axis=-1)
    nll = np.where(ok, M.gaussian_nll(np.where(ok[..., None], est, 0.0), cov, tru, dof=dof), np.nan)
    for suffix, mask in (("", ok), ("_hidden", ok & hidden), ("_hidden_early", ok & early),
                         ("_hidden_late", ok & hidden & ~early)):
        v = nll[mask]
        out[f"nll{suffix}"] = float(np.mean(v)) if v.size else math.nan
        out[f"nll{suffix}_median"] = float(np.median(v)) if v.size else math.nan
        for level, c in M.coverage(est[mask], cov[mask], tru[mask], dof=dof[mask]).items():
            out[f"cover{int(level * 100)}{suffix}"] = c
    # calibration of the probabilities
    rel = {}
    for name, p, y in (("plausible", p_pl.ravel(), ~held.ravel()), ("isIn", p_in.ravel(), y_in.ravel()),
                       ("isOnTop", p_on.ravel(), y_on.ravel())):
        out[f"brier_{name.lower()}"] = M.brier_score(p, y)
        bins = M.reliability_bins(p, y)
        out[f"ece_{name.lower()}"] = M.ece_from_bins(bins)
        rel[name] = bins
    out["reliability"] = rel
    if frames is not None:
        out.update(_tracking_scores(dyn_ids, truth, frames, steps, est, cov, tru, vis, run.gate_actions))
    return out


def _tracking_scores(dyn_ids, truth, frames, steps, est, cov, tru, vis, gate_actions=None) -> dict:
    """Re-appearance and NEES metrics (:mod:`experiments.evaluation.tracking_metrics`) of a run; with the Kalman
    tracker's ``gate_actions`` (see :class:`~experiments.evaluation.method_steps.MethodRun`), a re-appearance is
    inside the gate when the tracker accepted it."""
    from experiments.evaluation.tracking_metrics import nees_scores, reappearance_scores

    f_count, d_count = len(frames), len(dyn_ids)
    det_pos = np.full((f_count, d_count, 3), np.nan)
    det_std = np.full((f_count, d_count), np.nan)
    for i, f in enumerate(frames):
        for k, oid in enumerate(dyn_ids):
            d = f.objects.get(oid)
            if d is not None:
                det_pos[i, k] = d.position
                det_std[i, k] = np.nan if d.position_std is None else d.position_std
    det_t = np.array([f.t for f in frames])
    rows = _truth_rows_at(truth, list(det_t))
    true_pos = np.array([[r["objects"][o]["position"] for o in dyn_ids] for r in rows]).reshape(f_count, d_count, 3)
    accepted = None
    if gate_actions is not None:
        accepted = np.array([[gate_actions.get((i, oid)) == "accepted" for oid in dyn_ids] for i in range(f_count)],
                            dtype=bool).reshape(f_count, d_count)
    out = reappearance_scores(np.array([s.t for s in steps]), est, cov, det_t, det_pos, det_std, true_pos,
                              accepted=accepted)
    out.update(nees_scores(est, cov, tru, vis))
    return out
