"""The particle estimator: K perturbed Bullet worlds weighted into a belief.

``SceneEstimator(scene, config, rng).update(frame)`` runs one reasoning step when the stream's time has
advanced by the configured horizon, and returns a :class:`~estimator.belief.Belief` (``None`` for
frames that only update the perception memory). With one particle and :meth:`NoiseConfig.off` it *is*
the physics reasoner of Sallami et al. (IROS 2019), its "paper mode".

This module is the algorithm, a sequential Monte Carlo loop; what it runs on is apart:

* :class:`~estimator.perception_memory.PerceptionMemory`: last perceived pose, time and velocity of
  each object, and its tracked hand; perceived = seen within ``t_perceived``;
* :class:`~estimator.model.SceneModel`: how a particle moves (teleports, releases, held targets,
  process noise), what physics reports back (Place / Release) and how a particle is weighed (the
  terms of :mod:`estimator.likelihood`);
* :class:`~estimator.pool.WorldPool`: the K particle worlds, where physics runs (Alg. 1);
* :mod:`estimator.resampling`: normalisation, effective sample size and systematic resampling.

One update (time t, previous update at t0, ``n = round((t - t0) / time_step)`` simulation steps; the
first update simulates nothing, so that simulated time is the stream's time): perceive -> move (model)
-> propagate (pool) -> settle and weigh (model) -> summarise (belief, timeline) -> resample when the
effective sample size is below the threshold, then regularise (model).

With :class:`~estimator.config.AdaptiveConfig` enabled the number of particles K changes at
resampling: each update computes the count the belief needs (:func:`~estimator.adaptive.particles_needed`,
KLD-sampling) and resamples to it when it exceeds K or falls under ``shrink_below`` K (and, at
every resampling, resamples to it). Particle ``i`` always lives in the same world slot; the pool
parks the worlds of the slots beyond K and builds new ones as K first reaches them.
"""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from actions.events import recent_events, record_event_times
from actions.modes import FREE
from physics.scene import Scene

from .adaptive import particles_needed
from .belief import Belief, SpeedVariance, compute_belief
from .config import EstimatorConfig, reasoning_due
from .holding import places_after_update
from .likelihood import held_unseen_in_view
from .model import SceneModel, initial_poses
from .step import Move, Settled
from .observations import Frame
from .perception_memory import PerceptionMemory
from .person import with_person
from .pool import BatchOutput, WorldPool
from .resampling import effective_sample_size, keep_survivors_in_place, normalise_log_weights, systematic_resample
from .shard import camera_key
from .state import ParticleState
from .timeline import Timeline

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
        scene: the scene (static objects, shapes, initial poses, optional camera).
        config: estimator configuration; :meth:`EstimatorConfig.paper` for the paper's reasoner.
        rng: source of all randomness (default: ``numpy.random.default_rng(0)``).

    Particle state (:attr:`state`, a :class:`~estimator.state.ParticleState`; K particles, M objects),
    also readable as attributes: ``poses (K, M, 7)``, ``velocities (K, M, 6)``, ``params (K, M, 5)``
    (lateral / rolling / spinning friction, restitution, mass in kg), ``modes (K, M)`` int8
    (FREE / HELD), ``log_weights (K,)``, ``on_top (K, M, M+1)`` and ``is_in (K, M, M)`` (relations at
    the last update), ``event_t (K, M, 4)`` (latest Pick / Place / Release / Push times).
    ``known (M,)``: objects with a pose or perceived since.
    """

    poses = _StateField()
    velocities = _StateField()
    params = _StateField()
    modes = _StateField()
    log_weights = _StateField()
    on_top = _StateField()
    is_in = _StateField()
    event_t = _StateField()

    def __init__(self, scene: Scene, config: EstimatorConfig | None = None,
                 rng: np.random.Generator | None = None):
        self.scene = scene
        self.config = cfg = config or EstimatorConfig.paper()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.object_ids = scene.object_ids
        K, M = cfg.initial_particles, len(scene.objects)
        self.K, self.M = K, M
        self.pool = WorldPool(scene, K, cfg.workers, cfg.physics, cfg.worlds,
                              max_particles=cfg.max_particles if cfg.adaptive.enabled else None)
        try:
            self.memory = PerceptionMemory(scene, initial_poses(scene)[0], cfg.reasoner, cfg.follow_hands,
                                           from_onset=cfg.moving_teleports, hands=cfg.hands)
            self.model = SceneModel(scene, cfg, self.memory, self.pool.initial_params)
            self.state: ParticleState = self.model.initial_state(self.rng)
        except BaseException:
            self.pool.close()
            if getattr(self, "model", None) is not None:
                self.model.close()
            raise
        self.static, self.dynamic, self.hollow = self.model.static, self.model.dynamic, self.model.hollow
        self._speed_variance = SpeedVariance(cfg.noise.covariance_speed_time, self.dynamic)
        self.timeline = Timeline(cfg.event_threshold)
        self.recoveries = 0
        self._weighed = np.zeros(self.M, dtype=bool)  # objects some evidence weighed since the last resampling
        self.reseeded = 0  # particles re-seeded from survivors (exploded simulations, dead workers)
        self.k_range = [K, K, 0]  # the fewest and the most particles over the updates, and their sum
        self.n_updates = 0
        self.last_belief: Belief | None = None
        self.t_frame: float | None = None
        self.t_tick: float | None = None
        self._last_frame: Frame | None = None  # the last observed frame (outliers dropped)
        self._detected_since_tick = np.zeros(M, dtype=bool)
        self._cameras_since_tick: dict | None = None  # cameras of the frames since the last update
        self._scene_camera_since_tick = False  # a frame without cameras (the scene's) since then
        self.last_hands: dict = {}  # the tracked hands of the last frame that had any

    @property
    def rejected_detections(self) -> int:
        """Detections and hands dropped so far for lying outside the scene's workspace."""
        return self.memory.rejected

    @property
    def known(self) -> np.ndarray:
        return self.model.known

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
    def update(self, frame: Frame) -> Belief | None:
        """Process one perception frame; returns the belief if a reasoning step ran, else None."""
        self.observe(frame)
        if not reasoning_due(self.t_tick, frame.t, self.config.reasoner.horizon):
            return None
        return self.step()

    def observe(self, frame: Frame) -> None:
        """Record one perception frame in the perception memory without running a reasoning step,
        however much time has passed (a live stream that fell behind: the frames that arrived during
        a long update are observed, and the next :meth:`step` simulates the whole elapsed time; the
        velocity fit keeps every frame). Raises ``ValueError`` when ``frame.t`` does not increase."""
        if self.t_frame is not None and not frame.t > self.t_frame:
            raise ValueError(f"frame time must increase: {frame.t} after {self.t_frame}")
        frame = self.memory.admit(frame)  # detections outside the workspace are outliers
        detected = self.memory.record(frame)
        self.t_frame = frame.t
        self._last_frame = frame
        self._detected_since_tick |= detected
        if frame.hands:
            self.last_hands = dict(frame.hands)
        if frame.cameras is None:
            self._scene_camera_since_tick = True
        else:
            own = self._cameras_since_tick if self._cameras_since_tick is not None else {}
            own.update((camera_key(c), c) for c in frame.cameras.values())
            self._cameras_since_tick = own

    def step(self) -> Belief:
        """Run a reasoning step at the time of the last frame :meth:`observe` recorded, whether or not
        a horizon has passed since the previous step (it simulates the whole elapsed time, at most
        ``max_gap``); returns the belief. Raises ``ValueError`` before any frame, or when no frame
        was observed since the last step."""
        frame = self._last_frame
        if frame is None or (self.t_tick is not None and not frame.t > self.t_tick):
            raise ValueError("step() needs a frame observed since the last reasoning step")
        detected = self._detected_since_tick
        self._detected_since_tick = np.zeros(self.M, bool)
        cameras = self._tick_cameras()
        belief = self._tick(frame, detected, cameras)
        self.last_belief = belief
        return belief

    def _tick_cameras(self) -> tuple | None:
        """The cameras that took the frames since the last update, and forget them: None when every
        frame was the scene camera's (old streams: the pool asks the scene camera, as always), else
        each distinct camera once (the scene's too if one frame was its)."""
        own, scene_cam = self._cameras_since_tick, self._scene_camera_since_tick
        self._cameras_since_tick, self._scene_camera_since_tick = None, False
        if own is None:
            return None
        cams = list(own.values())
        if scene_cam and self.scene.camera is not None and camera_key(self.scene.camera) not in own:
            cams.insert(0, self.scene.camera)
        return tuple(cams)

    def _tick(self, frame: Frame, detected: np.ndarray, cameras: tuple | None = None) -> Belief:
        """One reasoning step at ``frame.t``; ``detected (M,)``: objects detected since the last one;
        ``cameras``: those that took the frames since then (None: the scene's)."""
        cfg, model, K = self.config, self.model, self.K
        t = frame.t
        # the first update only places the objects; after a gap, at most max_gap is simulated
        dt = 0.0 if self.t_tick is None else min(t - self.t_tick, cfg.reasoner.max_gap)
        n_steps = int(round(dt / cfg.physics.time_step))
        # perceive
        perceived = self.memory.perceived(t)
        # move (model), propagate (pool), settle (model)
        move = model.move(self.state, frame, detected, perceived, dt, self.rng, cameras)
        batch = model.batch(move, self.state, *self.pool.cache.loads(move.poses, move.velocities, move.fused))
        out = self.pool.run(batch, n_steps, cfg.reasoner.d_sim_perc, cfg.lazy_checks, cfg.moving_teleports,
                            cameras=cameras)  # None: the scene's camera
        bad = self._reset_exploded(out, move.poses, move.modes, t)
        # what the worlds hold now, before the model sets velocities (a ball let go falls at its speed)
        produced = (out.poses.copy(), out.velocities.copy())
        settled = model.settle(self.state, move, out, t, dt, detected, perceived)
        # weigh (the model's terms)
        evidence = model.evidence(move, settled, out, frame, detected, perceived, self.state.unseen_in_view)
        logw = model.log_weight(self.state.log_weights, evidence)
        weights, _ = normalise_log_weights(logw)
        if not np.any(np.isfinite(logw)):
            logw, weights = self._recover(t, settled, detected)
        ess = effective_sample_size(weights)
        # commit
        hidden = places_after_update(self.state, evidence, settled, t, self.rng, cfg.visibility_threshold)
        self._commit(move, settled, logw, bad, held_unseen_in_view(evidence, cfg.visibility_threshold), hidden,
                     produced)
        self.memory.end_tick(perceived, detected, settled.tick_vel)
        self.t_tick = t
        self.n_updates += 1
        # summarise
        record_event_times(self.state.event_t, settled.codes, t, settled.times, self.state.push_decided)
        step_events = recent_events(self.state.event_t, weights, t, cfg.event_window, self.object_ids,
                                    threshold=cfg.hypothesis_min_p, push_decided=self.state.push_decided)
        belief = compute_belief(t, self.object_ids, self.known, perceived, settled.poses, weights, settled.modes,
                                settled.on_top, settled.is_in, step_events, ess, self.static, cfg.hypothesis_min_p,
                                cov_floor=cfg.noise.covariance_floor_std ** 2,
                                dof=cfg.noise.position_dof or math.inf, params=self.state.params)
        belief = self._speed_variance(belief, detected, dt)
        n, resize = K, False
        if cfg.adaptive.enabled:  # the count this belief needs (resampled to below), and the K that made it
            n = particles_needed(settled.poses, settled.modes, weights, self.known & self.dynamic, cfg.adaptive)[0]
            resize = n > K or n < cfg.adaptive.shrink_below * K
            belief = dataclasses.replace(belief, n_particles=K)
        self.k_range = [min(self.k_range[0], K), max(self.k_range[1], K), self.k_range[2] + K]
        if self.scene.person is not None:  # P(visible to) and P(reachable by) the person
            belief = with_person(belief, self.pool, self.scene.person, settled.poses, weights,
                                 np.flatnonzero(self.known & self.dynamic), self.known, self.object_ids,
                                 self.last_hands, cfg.visibility_threshold)
        self._update_timeline(t, belief)
        # resample; particles whose simulation exploded or whose worker died take a survivor's state
        self._weighed |= detected | np.any(evidence.visible >= cfg.visibility_threshold, axis=0)
        if K > 1 and (ess < cfg.resample_threshold * K or resize):
            self._resample(weights, self.known & self.dynamic & ~perceived, settled, n)
        elif K > 1 and np.any(bad) and np.any(weights > 0):
            self._reseed(bad, weights)
        if K > 1 and np.any(bad) and np.any(weights > 0):
            self.reseeded += int(bad.sum())
        return belief

    # -- pieces of the update -------------------------------------------------------------------------
    @staticmethod
    def _reset_exploded(out: BatchOutput, poses: np.ndarray, modes: np.ndarray, t: float) -> np.ndarray:
        """Particles ``(K,)`` whose simulation exploded (or whose worker died) get back their state
        before physics, at rest (in ``out``, in place; the model weighs them zero, and the update
        ends by giving them a survivor's state). Returns their mask."""
        bad = ~out.finite
        if np.any(bad):
            log.warning("t=%.3f: %d particle simulation(s) exploded or lost; they are re-seeded from the "
                        "others", t, bad.sum())
            out.poses[bad] = poses[bad]
            out.velocities[bad] = 0.0
            out.modes[bad] = modes[bad]
        return bad

    def _recover(self, t: float, settled: Settled, detected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every particle has zero weight: the model re-seeds the detected objects ``(M,)`` (in
        ``settled``, in place); returns uniform log-weights and weights ``(K,)``."""
        self.recoveries += 1
        log.warning("t=%.3f: every particle has zero weight; re-seeding detected objects from perception", t)
        self.model.reseed(settled.poses, settled.velocities, detected, self.rng)
        return np.zeros(self.K), np.full(self.K, 1.0 / self.K)

    def _commit(self, move: Move, settled: Settled, logw: np.ndarray, bad: np.ndarray,
                unseen_in_view: np.ndarray, hidden: tuple[np.ndarray, ...],
                produced: tuple[np.ndarray, np.ndarray]) -> None:
        """The particles after this update (the largest finite log-weight made 0); ``hidden``: see
        :func:`~estimator.holding.places_after_update`; ``produced``: the poses and velocities
        ``(K, M, 7)``, ``(K, M, 6)`` the worlds hold (entries the model changed since differ, and are
        loaded at the next update)."""
        self.pool.cache.hold(*produced, bad)  # exploded worlds must be reloaded from the arrays
        self.state = self.state.after_update(move, settled, logw, unseen_in_view, hidden, settled.modes == FREE)

    def _resample(self, weights: np.ndarray, hidden: np.ndarray, settled: Settled, n: int) -> None:
        """Systematic resampling to ``n`` particles (K changes with it), then the model's regularisation of
        hidden objects ``hidden (M,)`` and of the physical parameters. The worlds keep what they hold
        (the pool's :class:`~estimator.world_cache.WorldCache` follows the particles).

        Hidden objects that nothing weighed since the last resampling (never detected nor in view in
        any particle since, see :attr:`_weighed`), free and at rest in every particle, and supporting
        nothing, keep each particle's own values (:meth:`ParticleState.take`): the weights are about
        other objects, and resampling them too would only lose their spread (a cube picked up in
        plain view left a marble hidden in a bin one particle's position). They need no kernel."""
        anc = keep_survivors_in_place(systematic_resample(weights, self.rng, n))
        own = hidden & ~self._weighed & self.model.unweighable(settled)
        kernels = self.model.regularisation_kernels(self.state.poses, weights, hidden & ~own)
        self.state = self.state.take(anc, own)
        self._weighed = np.zeros(self.M, dtype=bool)
        self.pool.cache.follow(anc)  # (slots beyond n: the pool parks their worlds at its next run)
        self.K = self.model.K = n
        self.model.regularise(self.state, kernels, self.rng)

    def _reseed(self, bad: np.ndarray, weights: np.ndarray) -> None:
        """Particles ``bad (K,)`` take the state (and weight) of survivors drawn by ``weights (K,)``
        (zero for the bad ones); their worlds reload it at the next update."""
        anc = np.arange(self.K)
        anc[bad] = self.rng.choice(self.K, size=int(bad.sum()), p=weights)
        logw = self.state.log_weights[anc]
        self.state = self.state.take(anc)
        self.state.log_weights = logw
        self.pool.cache.follow(anc)

    def _update_timeline(self, t: float, belief: Belief) -> None:
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

    # -- convenience ---------------------------------------------------------------------------------
    def run(self, frames) -> list[Belief]:
        """Process an iterable of frames; returns the beliefs of the reasoning steps."""
        out = []
        for f in frames:
            b = self.update(f)
            if b is not None:
                out.append(b)
        return out
