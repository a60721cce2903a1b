"""Fit the held-object priors on the simulator's scenarios, on seeds the evaluation does not use.

What is fitted (see :class:`actions.modes.ModePriors` and :class:`estimator.config.NoiseConfig`):

* ``release_on_loss_carried`` / ``release_on_loss_still``: an object stops counting as perceived
  (``t_perceived`` after its last detection) while the tracked hand that was within
  :data:`~estimator.model.hand_memory.HAND_RADIUS` of it at that detection held it in truth. The
  hand has *carried* it when it moved more than ``carry_distance`` (smoothed as the estimator does)
  in between, else it is *still*. The prior is the fraction of such losses where the object was in
  truth no longer held at the loss, with Laplace's rule ``(released + 1) / (losses + 2)`` (no data
  gives 0.5).
* ``release_hidden``: of the carried losses where the object was still held at the loss, the
  fraction let go before it was detected again (or the run ended), with Laplace's rule.
* ``put_down_hidden``: of the objects let go while hidden (the hits of ``release_hidden``), the
  fraction put down (at rest at most ``push_lift`` below where they were let go), not dropped;
  Laplace's rule.
* ``put_down_touched``: of the stretches out of view in which an object held in truth rests on
  something and the tracked hand then rises more than ``carry_distance``, the fraction where the
  object was no longer held when the hand had risen; Laplace's rule.
* ``held_offset_std``: the estimator's perception memory replayed on the stream (with the
  ``EstimatorConfig.hands`` given: filtered hands, averaged offsets); over the frames where an
  object is held in truth and not detected, after a detection with a tracked hand within that
  radius, the root-mean-square per axis of the true position minus where the memory puts it (the
  hand now plus the object's offset to it:
  :meth:`~estimator.model.perception_memory.PerceptionMemory.hand_target`).
* ``hand_std`` (:class:`~estimator.config.HandConfig` ``measurement_std``): over the frames with a
  tracked hand, the root-mean-square per axis of the tracked minus the true hand.
* ``held_out_of_reach``: over the frames with a tracked hand where an object is held in truth and
  detected, the fraction where its detection lies farther than
  :data:`~estimator.model.hand_memory.HAND_RADIUS` from every tracked hand; Laplace's rule.
* ``hand_occlusion``: over the frames where an object is held in truth and the scene alone (the
  estimator's worlds: no hand, no person) would show it to the camera, the fraction where the truth
  (with the hand and the person) does not; again with Laplace's rule. Every held frame counts:
  counting only those where the hand has carried the object since it was last visible (when the
  estimator applies the allowance) would select the unseen ones (0.92 instead of 0.1 on the
  built-in scenarios).
* ``release_accel`` (:class:`~estimator.config.ReasonerConfig`, m/s^2): the estimator's perception
  memory replayed on the stream, reasoning every ``horizon`` as the estimator does, and again on
  the stream as the Kalman tracker filters it (the estimator takes both: a filtered drop
  accelerates less); at each step, every object held in truth at the previous step, detected since
  and perceived moving down at ``RELEASE_DOWN_SPEED`` (0.3 m/s) or more is a sample of its perceived
  vertical acceleration (as the Release rule measures it), labelled by whether the truth still holds it. The threshold is the one that misclassifies
  the fewest samples (a hand lowering an object faster is read as a drop; a drop slower, as still
  held, until the next step), the middle of the interval of such thresholds; it applies only with
  nothing under the object, which this count does not check.
* ``accel_std`` (:class:`~estimator.applications.tracker.TrackerConfig`, m/s^2): over the truth's frames where
  an object is held (in a hand, which moves it as no physics does), its acceleration per axis from
  second differences of the true positions; the 99th percentile of their magnitudes, a robust
  maximum. A constant-velocity Kalman filter whose white acceleration is of the order of the largest
  acceleration it must follow (not the RMS, which the still stretches of a carry pull down) trails a
  carry's start and stop by little; the RMS is reported beside it.

Only scenarios whose perception tracks hands count. Pure counting over simulated streams, seeded by
the scenario's seed, under one or several truth engines (Bullet, MuJoCo: all runs counted together);
the result is a dictionary of the fitted values and their counts, and with several engines the fit
on each engine alone and its held-out log-likelihood on the other's runs (:func:`held_out`). The
per-run counts are in :mod:`experiments.evaluation.fit_counts`; this module tallies them and fits.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.config import EstimatorConfig
from experiments.evaluation.fit_counts import (
    Counts,
    Spread,
    count_accelerations,
    count_descents,
    count_hand_occlusion,
    count_losses,
    count_offsets,
    count_out_of_reach,
    count_set_downs,
)
from experiments.scenarios import list_scenarios, load_scenario
from experiments.simulation.simulator import simulate

FIT_SEEDS = range(100, 120)
"""Default seeds of the fit: the evaluation uses 0 .. 19."""


def best_threshold(negatives: list[float], positives: list[float]) -> tuple[float, int]:
    """The threshold ``a`` that misclassifies the fewest samples when values above ``a`` are read
    as positive, and that number of errors. The errors are constant between consecutive sample
    values; the threshold is the middle of the first run of best intervals (beyond the extreme
    samples, an interval of width 1)."""
    neg, pos = np.asarray(negatives, float), np.asarray(positives, float)
    values = np.unique(np.concatenate([neg, pos]))
    if len(values) == 0:
        raise ValueError("best_threshold needs samples")
    edges = np.concatenate([[values[0] - 1.0], values, [values[-1] + 1.0]])
    # on [edges[k], edges[k + 1]) a negative above edges[k] and a positive at or below it are wrong
    errors = np.array([np.sum(neg > e) + np.sum(pos <= e) for e in edges[:-1]])
    i = j = int(np.argmin(errors))
    while j + 1 < len(errors) and errors[j + 1] == errors[i]:
        j += 1
    return float(0.5 * (edges[i] + edges[j + 1])), int(errors[i])


@dataclass
class Tally:
    """Everything the fit counts over a set of runs (:meth:`add` one run; :meth:`merge`)."""

    carried: Counts = field(default_factory=Counts)
    still: Counts = field(default_factory=Counts)
    hidden: Counts = field(default_factory=Counts)
    occluded: Counts = field(default_factory=Counts)
    put_down: Counts = field(default_factory=Counts)
    touched: Counts = field(default_factory=Counts)
    reach: Counts = field(default_factory=Counts)
    spread: Spread = field(default_factory=Spread)
    hand_error: Spread = field(default_factory=Spread)
    held_down: list = field(default_factory=list)
    let_go_down: list = field(default_factory=list)
    accels: list = field(default_factory=list)

    def add(self, result, cfg: EstimatorConfig) -> None:
        """Count one run (``result``: the simulator's) replayed with ``cfg``."""
        for filtered in (False, True):  # raw detections, and as the Kalman tracker filters them
            count_descents(result, cfg.reasoner, self.held_down, self.let_go_down, filtered=filtered)
        count_losses(result.observations, result.truth, cfg.reasoner, cfg.priors, self.carried, self.still,
                     self.hidden, self.put_down, cfg.hands)
        count_offsets(result, cfg, self.spread, self.hand_error)
        count_set_downs(result.observations, result.truth, cfg.priors, self.touched, cfg.hands)
        count_hand_occlusion(result, cfg.visibility_threshold, self.occluded)
        count_out_of_reach(result.observations, result.truth, self.reach)
        count_accelerations(result.truth, self.accels)

    def merge(self, other: "Tally") -> "Tally":
        """The counts of both tallies together (a new tally)."""
        out = Tally()
        for name in BERNOULLI_PRIORS.values():
            a, b = getattr(self, name), getattr(other, name)
            setattr(out, name, Counts(a.hits + b.hits, a.n + b.n))
        for name in GAUSSIAN_PRIORS.values():
            a, b = getattr(self, name), getattr(other, name)
            setattr(out, name, Spread(a.ss + b.ss, a.n + b.n))
        for name in ("held_down", "let_go_down", "accels"):
            setattr(out, name, list(getattr(self, name)) + list(getattr(other, name)))
        return out


BERNOULLI_PRIORS = {"release_on_loss_carried": "carried", "release_on_loss_still": "still",
                    "release_hidden": "hidden", "put_down_hidden": "put_down", "put_down_touched": "touched",
                    "held_out_of_reach": "reach", "hand_occlusion": "occluded"}
"""Priors that are a probability (Laplace's rule over :class:`Counts`), by the tally field they count."""
GAUSSIAN_PRIORS = {"held_offset_std": "spread", "hand_std": "hand_error"}
"""Priors that are a standard deviation per axis (over :class:`Spread`), by their tally field."""


def fitted(t: Tally, names: list[str], seeds, engines=("bullet",)) -> dict:
    """The fitted values of a tally, with their counts (the format of :func:`fit_priors`)."""
    # no held object perceived moving down in these runs (one scenario, say): nothing to fit
    accel, accel_errors = (best_threshold(t.held_down, t.let_go_down) if t.held_down or t.let_go_down
                           else (None, 0))
    carry = np.abs(np.asarray(t.accels, float))
    return {"release_on_loss_carried": round(t.carried.p, 3), "release_on_loss_still": round(t.still.p, 3),
            "release_hidden": round(t.hidden.p, 3), "put_down_hidden": round(t.put_down.p, 3),
            "put_down_touched": round(t.touched.p, 3), "held_out_of_reach": float(f"{t.reach.p:.2g}"),
            "hand_occlusion": round(t.occluded.p, 3), "held_offset_std": round(t.spread.std, 4),
            "hand_std": round(t.hand_error.std, 4),
            "release_accel": None if accel is None else round(accel, 2),
            "accel_std": round(float(np.percentile(carry, 99)), 1) if carry.size else float("nan"),
            "counts": {"accel_std": {"samples": int(carry.size),
                                     "rms": round(float(np.sqrt(np.mean(carry ** 2))), 2) if carry.size else None},
                       "held_offset_std": [round(t.spread.ss, 6), t.spread.n],
                       "hand_std": [round(t.hand_error.ss, 6), t.hand_error.n],
                       **{k: [getattr(t, v).hits, getattr(t, v).n] for k, v in BERNOULLI_PRIORS.items()},
                       "release_accel": {"errors": accel_errors, "held": len(t.held_down), "let_go": len(t.let_go_down),
                                         "held_max": round(max(t.held_down, default=float("nan")), 2),
                                         "let_go_min": round(min(t.let_go_down, default=float("nan")), 2)}},
            "scenarios": names, "seeds": [int(s) for s in seeds], "engines": list(engines)}


def _bernoulli_ll(p: float, c: Counts) -> float:
    p = min(max(p, 1e-12), 1 - 1e-12)
    return (c.hits * np.log(p) + (c.n - c.hits) * np.log(1 - p)) / c.n


def _gaussian_ll(std: float, s: Spread) -> float:
    var = std * std
    return float(-0.5 * np.log(2 * np.pi * var) - s.ss / (3 * s.n) / (2 * var))


def held_out(fit: dict, t: Tally) -> dict:
    """How well ``fit`` (:func:`fitted` of other runs) explains the runs of ``t``: per prior, the
    mean log-likelihood per sample under ``fit`` (``ll``) and under the fit of ``t`` itself
    (``ll_own``, the best any value does on these samples; their difference is what fitting on the
    other runs costs), and ``n`` samples. Probabilities are Bernoulli, standard deviations zero-mean
    Gaussian per axis; ``release_accel`` reports the fraction of ``t``'s samples the fitted threshold
    misclassifies (``error_rate``, ``error_rate_own``). Priors without samples in ``t`` are left out."""
    own = fitted(t, [], [])
    out: dict[str, dict] = {}
    for key, name in BERNOULLI_PRIORS.items():
        c = getattr(t, name)
        if c.n:
            out[key] = {"ll": round(float(_bernoulli_ll(fit[key], c)), 4),
                        "ll_own": round(float(_bernoulli_ll(own[key], c)), 4), "n": c.n}
    for key, name in GAUSSIAN_PRIORS.items():
        sp = getattr(t, name)
        if sp.n and fit[key] > 0:
            out[key] = {"ll": round(_gaussian_ll(fit[key], sp), 3), "ll_own": round(_gaussian_ll(own[key], sp), 3),
                        "n": sp.n}
    if fit.get("release_accel") is not None and (t.held_down or t.let_go_down):
        def rate(a):
            wrong = np.sum(np.asarray(t.held_down) > a) + np.sum(np.asarray(t.let_go_down) <= a)
            return round(float(wrong) / (len(t.held_down) + len(t.let_go_down)), 4)
        out["release_accel"] = {"error_rate": rate(fit["release_accel"]), "error_rate_own": rate(own["release_accel"]),
                                "n": len(t.held_down) + len(t.let_go_down)}
    return out


def fit_priors(scenarios: list[str] | None = None, seeds=FIT_SEEDS, config: EstimatorConfig | None = None,
               engines=("bullet",)) -> dict:
    """Fit on ``scenarios`` (default: every built-in one with tracked hands) x ``seeds`` x truth
    ``engines`` (:data:`~experiments.simulation.simulator.ENGINES`), all runs together.

    Returns ``{"release_on_loss_carried": p, "release_on_loss_still": p, "release_hidden": p, "put_down_hidden": p,
    "put_down_touched": p,
    "held_out_of_reach": p, "hand_occlusion": p, "held_offset_std": m, "hand_std": m, "release_accel": m/s^2,
    "accel_std": m/s^2,
    "counts": {name: [hits, n] (release_accel: errors, samples, extremes)}, "scenarios": [...],
    "seeds": [...], "engines": [...]}``; ``release_accel`` is None when no held object was perceived
    moving down. With several engines also ``"by_engine": {engine: fit on its runs alone}`` and
    ``"held_out": {"A->B": held_out(fit on A's runs, B's runs)}`` for every ordered pair (how well a
    fit on one engine's worlds explains the other's). ``config``: the estimator configuration
    replayed (reasoner, priors, hands; default :class:`~estimator.config.EstimatorConfig`)."""
    cfg = config or EstimatorConfig()
    names = [n for n in (scenarios or list_scenarios()) if load_scenario(n).perception.hands_tracked]
    tallies = {}
    for engine in engines:
        tally = Tally()
        for name in names:
            for seed in seeds:
                tally.add(simulate(name, int(seed), engine=engine), cfg)
        tallies[engine] = tally
    pooled = Tally()
    for tally in tallies.values():
        pooled = pooled.merge(tally)
    out = fitted(pooled, names, seeds, engines)
    if len(tallies) > 1:
        alone = {e: fitted(t, names, seeds, (e,)) for e, t in tallies.items()}
        out["by_engine"] = {e: {k: v for k, v in f.items() if k not in ("counts", "scenarios", "seeds")}
                            for e, f in alone.items()}
        out["held_out"] = {f"{a}->{b}": held_out(alone[a], tallies[b])
                           for a in tallies for b in tallies if a != b}
    return out
