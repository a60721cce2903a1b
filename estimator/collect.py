"""What the filter hands each update's weighted particles to: the belief and what is built from it.

:class:`Collectors` turns the particles after an update into the :class:`~estimator.belief.Belief`
(recent events, hypotheses, relations, the widening of moving objects' covariances), adds the
person's view when the scene names a person (:mod:`estimator.applications.person`) and records the timeline
(:class:`~estimator.timeline.Timeline`). K particles, M objects.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from actions.events import recent_events

from .applications.person import with_person
from .belief import Belief, SpeedVariance, compute_belief
from .timeline import Timeline

__all__ = ["Belief", "Collectors"]


class Collectors:
    """The belief of each update and its consumers, for ``scene`` under ``config``
    (:class:`~estimator.config.EstimatorConfig`); ``pool``: the particle worlds, where the person's
    view casts its rays. ``timeline``: every update's facts and events so far."""

    def __init__(self, scene, config, pool, dynamic: np.ndarray, static: np.ndarray):
        self.scene, self.config, self.pool = scene, config, pool
        self.object_ids = scene.object_ids
        self.dynamic, self.static = dynamic, static
        self.timeline = Timeline(config.event_threshold)
        self._speed_variance = SpeedVariance(config.noise.covariance_speed_time, dynamic)

    def __call__(self, t: float, state, settled, weights: np.ndarray, ess: float, known: np.ndarray,
                 perceived: np.ndarray, detected: np.ndarray, dt: float, hands: dict,
                 n_particles: int | None = None) -> Belief:
        """The belief at ``t`` (s) of the particles ``state`` (:class:`~estimator.state.ParticleState`,
        its events recorded) after the update ``settled`` (:class:`~estimator.model.step.Settled`), weighed
        ``weights (K,)`` (effective sample size ``ess``); ``known``, ``perceived`` and ``detected``
        ``(M,)`` bool; ``dt`` (s) since the previous update; ``hands``: the tracked hands;
        ``n_particles``: the K reported (adaptive runs; None: not reported). Records the timeline."""
        cfg = self.config
        events = recent_events(state.event_t, weights, t, cfg.event_window, self.object_ids,
                               threshold=cfg.hypothesis_min_p, push_decided=state.push_decided)
        belief = compute_belief(t, self.object_ids, known, perceived, settled.poses, weights, settled.modes,
                                settled.on_top, settled.is_in, events, ess, self.static, cfg.hypothesis_min_p,
                                cov_floor=cfg.noise.covariance_floor_std ** 2,
                                dof=cfg.noise.position_dof or math.inf, params=state.params)
        belief = self._speed_variance(belief, detected, dt)
        if n_particles is not None:
            belief = replace(belief, n_particles=n_particles)
        if self.scene.person is not None:  # P(visible to) and P(reachable by) the person
            belief = with_person(belief, self.pool, self.scene.person, settled.poses, weights,
                                 np.flatnonzero(known & self.dynamic), known, self.object_ids, hands,
                                 cfg.visibility_threshold)
        self._record(t, belief)
        return belief

    def _record(self, t: float, belief: Belief) -> None:
        """The timeline's facts (relations, held, perceived) and events of ``belief``."""
        facts = {}
        for r in belief.relations:
            facts[(r["predicate"], r["subject"], r["object"])] = r["p"]
        for oid, ob in belief.objects.items():
            if ob.p_held > 0:
                facts[("isHeld", oid, None)] = ob.p_held
            if ob.perceived:
                facts[("isPerceived", oid, None)] = 1.0
        self.timeline.observe_facts(t, facts)
        self.timeline.observe_events(t, belief.events)
