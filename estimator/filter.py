"""The particle estimator: K perturbed Bullet worlds weighted into a belief.

``SceneEstimator(scene, config, rng).update(frame)`` runs one reasoning step when the stream's time has
advanced by the configured horizon, and returns a :class:`~estimator.belief.Belief` (``None`` for
frames that only update the perception memory). With one particle and :meth:`NoiseConfig.off` it *is*
the physics reasoner of Sallami et al. (IROS 2019), its "paper mode".

This module is the algorithm, a sequential Monte Carlo loop; what it runs on is apart:

* :class:`~estimator.model.perception_memory.PerceptionMemory`: last perceived pose, time and velocity of
  each object, and its tracked hand; perceived = seen within ``t_perceived``;
* :class:`~estimator.model.SceneModel`: how a particle moves (teleports, releases, held targets,
  process noise), what physics reports back (Place / Release) and how a particle is weighed (the
  terms of :mod:`estimator.model.likelihood`);
* :class:`~estimator.worlds.pool.WorldPool`: the K particle worlds, where physics runs (Alg. 1);
* :mod:`estimator.resampling`: normalisation, effective sample size and systematic resampling.

One update (time t, previous update at t0, ``n = round((t - t0) / time_step)`` simulation steps; the
first update simulates nothing, so that simulated time is the stream's time): perceive -> move (model)
-> propagate (pool) -> settle and weigh (model) -> summarise (belief, timeline) -> resample when the
effective sample size is below the threshold, then regularise (model).

With :class:`~estimator.config.AdaptiveConfig` enabled the number of particles K changes at
resampling or splitting: each update computes the count the belief needs
(:func:`~estimator.adaptive.particles_needed`, KLD-sampling). When it exceeds K the particles are
split, not resampled: the new ones are copies of particles drawn by weight, every weight shared
among a particle and its copies, and only the copies are regularised
(:func:`~estimator.resampling.split_ancestors`). When it falls under ``shrink_below`` K the filter
resamples to it, and every resampling resamples to it. Particle ``i`` always lives in the same world
slot; the pool parks the worlds of the slots beyond K and builds new ones as K first reaches them.
With :class:`~estimator.config.BudgetConfig` enabled (live use), the count is also capped by what
the machine affords: each step's wall time (the worlds' part of it scaling with K) against the
stream time it covered sets the cap (:func:`~estimator.config.budget_cap`), and the filter
resamples to it when it holds more.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from .collect import Belief, Collectors
from .config import EstimatorConfig, budget_cap, reasoning_due
from .model import SceneModel
from .resampling import (
    effective_sample_size,
    keep_survivors_in_place,
    normalise_log_weights,
    split_ancestors,
    systematic_resample,
)
from .worlds.pool import WorldPool

log = logging.getLogger(__name__)


class _StateField:
    """An attribute of the estimator that is a field of its :class:`ParticleState`."""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, objtype=None):
        return self if obj is None else getattr(obj.state, self.name)

    def __set__(self, obj, value) -> None:
        setattr(obj.state, self.name, value)


class SceneEstimator:
    """Particle filter over pybullet worlds for one scene.

    Args:
        scene: the scene (:class:`~physics.scene.Scene`: static objects, shapes, initial poses,
            optional camera).
        config: estimator configuration; :meth:`EstimatorConfig.paper` for the paper's reasoner.
        rng: source of all randomness (default: ``numpy.random.default_rng(0)``).
        mechanisms: ``model -> list`` of the scene model's mechanisms (default: those the configuration
            asks for, :func:`~estimator.model.mechanisms.mechanisms_for`); see
            :class:`~estimator.model.SceneModel`.

    Particle state (:attr:`state`, a :class:`~estimator.state.ParticleState`; K particles, M objects),
    also readable as attributes: ``poses (K, M, 7)``, ``velocities (K, M, 6)``, ``params (K, M, 5)``
    (lateral / rolling / spinning friction, restitution, mass in kg), ``modes (K, M)`` int8
    (FREE / HELD), ``log_weights (K,)``, ``on_top (K, M, M+1)`` and ``is_in (K, M, M)`` (relations at
    the last update), ``event_t (K, M, 4)`` (latest Pick / Place / Release / Push times).
    ``known (M,)``: objects with a pose or perceived since. ``cap``: the most particles the
    compute budget allows now (the count configured without a budget); ``clock``: the wall clock
    (s) the budget times the steps with.
    """

    poses = _StateField()
    velocities = _StateField()
    params = _StateField()
    modes = _StateField()
    log_weights = _StateField()
    on_top = _StateField()
    is_in = _StateField()
    event_t = _StateField()

    def __init__(self, scene, config: EstimatorConfig | None = None, rng: np.random.Generator | None = None, *,
                 mechanisms=None):
        self.scene = scene
        self.config = cfg = config or EstimatorConfig.paper()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.object_ids = scene.object_ids
        K, M = cfg.initial_particles, len(scene.objects)
        self.M = M
        self.pool = WorldPool(scene, K, cfg.workers, cfg.physics, cfg.worlds,
                              max_particles=cfg.max_particles if cfg.varying_count else None)
        try:
            self.model = SceneModel(scene, cfg, self.pool.initial_params, mechanisms=mechanisms)
            self.state = self.model.initial_state(self.rng)
        except BaseException:
            self.pool.close()
            if getattr(self, "model", None) is not None:
                self.model.close()
            raise
        self.static, self.dynamic, self.hollow = self.model.static, self.model.dynamic, self.model.hollow
        self.collect = Collectors(scene, cfg, self.pool, self.dynamic, self.static)
        self.reseeded = 0  # particles re-seeded from survivors (exploded simulations, dead workers)
        self.k_range = [K, K, 0]  # the fewest and the most particles over the updates, and their sum
        self.n_updates = 0
        self.cap = cfg.max_particles
        self.clock = time.perf_counter
        self.last_belief: Belief | None = None
        self.t_tick: float | None = None
        self._pending: tuple | None = None  # a resampling or split deferred by step(defer=True): (method, args)

    # -- what the state, the model and the collectors hold ----------------------------------------------
    @property
    def K(self) -> int:
        """The number of particles now (it changes with an adaptive count)."""
        return len(self.state.log_weights)

    @property
    def memory(self):
        """The perception memory (:class:`~estimator.model.perception_memory.PerceptionMemory`)."""
        return self.model.memory

    @property
    def timeline(self):
        """The timeline of facts and events so far (:class:`~estimator.timeline.Timeline`)."""
        return self.collect.timeline

    @property
    def known(self) -> np.ndarray:
        return self.model.known

    @property
    def t_frame(self) -> float | None:
        """Time (s) of the last frame observed (None before any)."""
        return self.model.inputs.t_frame

    @property
    def last_hands(self) -> dict:
        """The tracked hands of the last frame that had any."""
        return self.model.inputs.last_hands

    @property
    def recoveries(self) -> int:
        """Updates after which every particle had zero weight (detected objects re-seeded)."""
        return self.model.recoveries

    @property
    def rejected_detections(self) -> int:
        """Detections and hands dropped so far for lying outside the scene's workspace."""
        return self.model.memory.rejected

    # -- life cycle -----------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the particle worlds (and worker processes)."""
        self.pool.close()
        self.model.close()

    def __enter__(self) -> "SceneEstimator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the update -----------------------------------------------------------------------------------
    def update(self, frame) -> Belief | None:
        """Process one perception frame (:class:`~estimator.observations.Frame`); returns the belief if
        a reasoning step ran, else None."""
        self.observe(frame)
        if not reasoning_due(self.t_tick, frame.t, self.config.reasoner.horizon):
            return None
        return self.step()

    def observe(self, frame) -> None:
        """Record one perception frame without running a reasoning step, however much time has passed
        (a live stream that fell behind: the frames that arrived during a long update are observed,
        and the next :meth:`step` simulates the whole elapsed time; the velocity fit keeps every
        frame). Raises ``ValueError`` when ``frame.t`` does not increase."""
        self.model.observe(frame)

    def step(self, defer: bool = False) -> Belief:
        """Run a reasoning step at the time of the last frame :meth:`observe` recorded, whether or not
        a horizon has passed since the previous step (it simulates the whole elapsed time, at most
        ``max_gap``); returns the belief. Raises ``ValueError`` before any frame, or when no frame
        was observed since the last step.

        The step: the model proposes (its moves and the worlds' input), the worlds run, the model
        weighs (settles, and sums its terms) and commits the particles, the collectors make the
        belief; then resampling, when the effective sample size is low or the count must change.
        ``defer``: the resampling (or re-seeding) is left for :meth:`finish`, which the next step
        runs first if no one has: the belief is out sooner, and a live loop resamples while it waits
        for frames (:class:`~experiments.live.LiveLoop`). Until then :attr:`state` holds the weighed
        particles the belief was made of. The results are the same either way."""
        if self._pending is not None:
            self.finish()
        t_start = self.clock()
        t = self.model.inputs.t_frame
        if t is None or (self.t_tick is not None and not t > self.t_tick):
            raise ValueError("step() needs a frame observed since the last reasoning step")
        cfg, model, K = self.config, self.model, len(self.state.log_weights)
        # the first update only places the objects; after a gap, at most max_gap is simulated
        dt = 0.0 if self.t_tick is None else min(t - self.t_tick, cfg.reasoner.max_gap)
        proposal = model.propose(self.state, dt, self.rng)
        t_worlds = self.clock()
        out = self.pool.advance(proposal.batch, int(round(dt / cfg.physics.time_step)), cfg.reasoner.d_sim_perc,
                                cfg.lazy_checks, proposal.moving_targets, proposal.cameras, proposal.move.fused,
                                cfg.freeze_unreachable, cfg.sleep_loads, proposal.move.placed_at_rest)
        t_worlds = self.clock() - t_worlds
        bad = ~out.finite  # exploded, or lost with their worker: weighed zero, then re-seeded
        if np.any(bad):
            log.warning("t=%.3f: %d particle simulation(s) exploded or lost; they are re-seeded from the "
                        "others", t, bad.sum())
        weighed = model.weigh(self.state, proposal, out, self.rng)
        weights, _ = normalise_log_weights(weighed.log_weights)
        ess = effective_sample_size(weights)
        self.state = model.commit(self.state, proposal, weighed, self.rng)
        self.t_tick = t
        self.n_updates += 1
        n = model.particles_needed(weighed.settled, weights) if cfg.adaptive.enabled else cfg.particles
        self.k_range = [min(self.k_range[0], K), max(self.k_range[1], K), self.k_range[2] + K]
        belief = self.collect(t, self.state, weighed.settled, weights, ess, model.known, proposal.perceived,
                              proposal.detected, dt, model.inputs.last_hands, K if cfg.varying_count else None)
        self.last_belief = belief
        if cfg.budget.enabled and dt > 0:
            self.cap = budget_cap(self.cap, K, self.clock() - t_start, t_worlds, max(dt, cfg.reasoner.horizon),
                                  cfg.budget, cfg.max_particles)
        n = min(n, self.cap)
        reseed = K > 1 and np.any(bad) and np.any(weights > 0)
        pending = None
        if K > 1 and (ess < cfg.resample_threshold * K or (n > K and reseed) or n < cfg.adaptive.shrink_below * K
                      or K > self.cap):
            pending = (self._resample, (weights, weighed.settled, proposal.perceived, n))
        elif K > 1 and n > K:
            pending = (self._grow, (weights, weighed.settled, proposal.perceived, n))
        elif reseed:
            pending = (self._reseed, (bad, weights))
        if reseed:
            self.reseeded += int(bad.sum())
        if defer:
            self._pending = pending
        elif pending is not None:
            pending[0](*pending[1])
        return belief

    def finish(self) -> None:
        """Run the resampling (or split, or re-seeding) the last :meth:`step` deferred, if any (see ``defer``)."""
        if self._pending is not None:
            run, args = self._pending
            self._pending = None
            run(*args)

    def _resample(self, weights: np.ndarray, settled, perceived: np.ndarray, n: int) -> None:
        """Systematic resampling to ``n`` particles (K changes with it); the state's arrays are taken
        generically (:meth:`~estimator.state.ParticleState.take`), the objects the model names keeping
        each particle's own values; then the model's regularisation. The worlds keep what they hold
        (the pool follows the particles)."""
        anc = keep_survivors_in_place(systematic_resample(weights, self.rng, n))
        own, kernels = self.model.before_resampling(self.state, settled, perceived, weights)
        before, self.state = self.state, self.state.take(anc, own)
        slid = self.model.after_resampling(self.state, kernels, self.rng, before, own)
        # (slots beyond n: the pool parks their worlds at its next run)
        self.pool.follow(anc, self.model.carried_at_rest(before, self.state, anc, own, self.pool.scene_boxes, slid))

    def _grow(self, weights: np.ndarray, settled, perceived: np.ndarray, n: int) -> None:
        """Grow to ``n`` particles by splitting, not resampling (:func:`~estimator.resampling.split_ancestors`):
        the particles stay in their slots with their worlds, the new ones are copies of particles
        drawn by weight, each particle's weight shared among it and its copies; then the model
        regularises the copies alone (:meth:`~estimator.model.SceneModel.after_growth`). The belief
        is the same weighted average, and only the new slots' worlds load."""
        anc, w = split_ancestors(weights, self.rng, n)
        _, kernels = self.model.before_resampling(self.state, settled, perceived, weights)
        self.state = self.state.take(anc)
        with np.errstate(divide="ignore"):
            self.state.log_weights = np.log(w / w.max())
        slid = self.model.after_growth(self.state, kernels, self.rng, np.arange(n) >= len(weights), w)
        self.pool.follow(anc, (slid, self.state.poses) if slid.any() else None)

    def _reseed(self, bad: np.ndarray, weights: np.ndarray) -> None:
        """Particles ``bad (K,)`` take the state (and weight) of survivors drawn by ``weights (K,)``
        (zero for the bad ones); their worlds reload it at the next update."""
        K = len(bad)
        anc = np.arange(K)
        anc[bad] = self.rng.choice(K, size=int(bad.sum()), p=weights)
        logw = self.state.log_weights[anc]
        self.state = self.state.take(anc)
        self.state.log_weights = logw
        self.pool.follow(anc)

    # -- convenience ---------------------------------------------------------------------------------
    def run(self, frames) -> list[Belief]:
        """Process an iterable of frames; returns the beliefs of the reasoning steps."""
        out = []
        for f in frames:
            b = self.update(f)
            if b is not None:
                out.append(b)
        return out
