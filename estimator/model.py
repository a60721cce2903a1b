"""The scene model: how a particle moves between two updates, and how it is weighed.

K particles, M objects; positions in metres, quaternions ``(x, y, z, w)``, times in seconds. The
model reads the :class:`~estimator.perception_memory.PerceptionMemory` and knows the scene and the
configuration; the particle filter (:class:`~estimator.filter.SceneEstimator`) owns the particles
and the worlds and calls, at each update:

1. :meth:`SceneModel.move`: teleports (Alg. 2) with contents carried, releases of held objects that
   are not perceived, targets of held objects (the perception, the tracked hand, or a drift),
   process noise on unperceived free objects, and what the physics must check and report;
2. :meth:`SceneModel.batch`: the pool's input for the move (physics itself is the pool's, Alg. 1);
3. :meth:`SceneModel.settle`: relations after physics, Place (a held object perceived at rest on
   a support) and Release in view (perceived falling), the update's events (:mod:`actions.episodes`);
4. :meth:`SceneModel.evidence` and :meth:`SceneModel.log_weight`: the terms of
   :mod:`estimator.likelihood` (:attr:`SceneModel.terms`);
5. after resampling, :meth:`SceneModel.regularise`: kernel jitter of hidden free objects and
   Liu-West shrinkage of the physical parameters.
"""
from __future__ import annotations

import logging

import numpy as np

from actions.episodes import EpisodeRule, carried, update_events
from actions.events import N_ACTIONS, record_event_times
from actions.modes import FREE, HELD, PUSH
from actions.push import REF_Z, empty_holds, late_picks
from physics.penetration import StaticGeometry
from physics.scene import Scene
from physics.visibility import sphere_occlusion

from .adaptive import particles_needed
from .config import RELEASE_DOWN_SPEED, EstimatorConfig
from .holding import dropped_behind_cover, places_after_update
from .inputs import StepInputs
from .likelihood import (DetectionTerm, Evidence, HandReachTerm, LogWeightTerm, ModeSwitchTerm, NegativeEvidenceTerm,
                         ProposalTerm, VelocityTerm, add_terms, exploded_log_likelihood, held_unseen_in_view)
from .mechanisms import PHASES, Draft, Mechanism, mechanisms_for
from .mechanisms.teleport import moving_beyond_noise
from .motion import out_of_reach, roll_released, rolled_along
from .noise import regularisation_kernels
from .observations import Frame
from .params import param_bounds, shrink_params
from .perception_memory import HAND_RADIUS, PerceptionMemory
from .pool import BatchInput, BatchOutput
from .relations import relations_and_support, supported_mask
from .resampling import effective_sample_size, normalise_log_weights
from .resting import slow
from .state import ParticleState
from .step import Move, Proposal, Settled, Weighed

log = logging.getLogger(__name__)


def initial_poses(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Initial poses ``(M, 7)`` of the scene's objects and which are known ``(M,)`` bool: objects
    without a pose are parked far away (at ``(50 + 3 m, 50, -50)``) until first perceived."""
    M = len(scene.objects)
    poses = np.zeros((M, 7))
    poses[:, 6] = 1.0
    known = np.zeros(M, dtype=bool)
    for i, o in enumerate(scene.objects):
        if o.position is not None:
            poses[i, :3] = o.position
            poses[i, 3:] = o.orientation
            known[i] = True
        else:
            poses[i, :3] = [50.0 + 3.0 * i, 50.0, -50.0]  # parked until first perceived
    return poses, known


def diverged_by(move: Move, out: BatchOutput) -> np.ndarray:
    """``(K, M)`` float: the divergence (m) at which physics overrode each free, checked object
    (the pool switched it to HELD and put it on its perception, Algorithm 1), NaN for the others
    (``Evidence.diverged``)."""
    over = move.check & (move.modes == FREE) & (out.modes == HELD)
    return np.where(over, out.max_divergence, np.nan)



CARRIER_SHIFT = 0.02
"""An object perceived moving and more than this (m) away horizontally from where it was still
(:meth:`~estimator.perception_memory.PerceptionMemory.shifted`) carries what is in or on it: those
get no events of their own (:meth:`SceneModel.settle`)."""

SURPRISE = 4.0
"""An object whose perceived velocity has been, on average (:meth:`SceneModel.note_surprise`), more
than two of its standard deviations away from what the particles predicted (squared, per axis, over
two axes: 4) has its frictions' kernel widened to ``NoiseConfig.param_widen`` at the next
resampling: every particle is wrong about how it slows down."""




class SceneModel:
    """How the particles of ``scene`` move and are weighed (see the module docstring).

    Args:
        scene: the scene. config: the estimator's configuration.
        memory: the perception memory the model reads (and whose velocities teleports reset).
        base_params: ``(M, 5)`` the scene's physical parameters (the worlds' initial ones).

    ``known (M,)``: objects with an initial pose or perceived since; ``terms``: the log-weight terms.
    """

    def __init__(self, scene: Scene, config: EstimatorConfig, base_params: np.ndarray,
                 memory: PerceptionMemory | None = None):
        self.scene = scene
        self.config = config
        self.memory = memory if memory is not None else PerceptionMemory(
            scene, initial_poses(scene)[0], config.reasoner, config.follow_hands,
            from_onset=config.moving_teleports, hands=config.hands)
        self.inputs = StepInputs(len(scene.objects), scene.camera)
        self.recoveries = 0  # updates after which every particle had zero weight (reseed)
        self.weighed = np.zeros(len(scene.objects), dtype=bool)  # objects weighed since the last resampling
        self.K, self.M = config.initial_particles, len(scene.objects)  # K changes with adaptive K (the filter sets it)
        self.static = np.array([o.static for o in scene.objects], dtype=bool)
        self.dynamic = ~self.static
        self.hollow = np.array(scene.hollow, dtype=bool)
        self.round = np.array([o.shape in ("sphere", "cylinder") for o in scene.objects], dtype=bool)
        self.ball_radius = np.array([o.radius if o.shape == "sphere" else np.nan for o in scene.objects])
        self.known = initial_poses(scene)[1]
        self.base_params = base_params
        self.param_bounds = param_bounds(config)
        self.perturbed = np.zeros((self.M, 5), dtype=bool)  # parameters the prior spreads (initial_state)
        self.surprise = np.zeros(self.M)  # how far the objects' motion is from the particles' (note_surprise)
        hr = config.reasoner
        self.episode_rule = EpisodeRule(hr.push_lift, hr.push_smoothing, hr.place_wait)
        self._just_initialised = np.zeros(self.M, dtype=bool)
        self.terms: tuple[LogWeightTerm, ...] = self.log_weight_terms()
        # the static bodies, to stop paths at their surfaces (config.static_clip)
        solid = bool(np.any(self.static)) or scene.floor
        self.geometry = StaticGeometry(scene, config.physics) if config.static_clip and solid else None
        self.mechanisms: list[Mechanism] = mechanisms_for(self)
        self._hooks = {phase: [getattr(m, phase) for m in self.mechanisms if hasattr(m, phase)] for phase in PHASES}

    def mechanism(self, kind: type) -> Mechanism:
        """The mechanism of class ``kind`` in :attr:`mechanisms` (``LookupError`` when there is none)."""
        for m in self.mechanisms:
            if isinstance(m, kind):
                return m
        raise LookupError(f"no {kind.__name__} among this model's mechanisms")

    def close(self) -> None:
        """Release the static geometry's pybullet client."""
        if self.geometry is not None:
            self.geometry.close()
            self.geometry = None

    def log_weight_terms(self) -> tuple[LogWeightTerm, ...]:
        """The terms a particle's log-weight is the sum of. A new term goes here."""
        nz, cfg = self.config.noise, self.config
        return (DetectionTerm(nz.position_std, nz.orientation_std, nz.outlier_prob),
                NegativeEvidenceTerm(nz.miss_prob, cfg.visibility_threshold, nz.hand_occlusion),
                ModeSwitchTerm(cfg.priors), HandReachTerm(cfg.priors.held_out_of_reach), ProposalTerm(),
                VelocityTerm(nz.velocity_slack, nz.outlier_prob))

    # -- the contract with the filter ----------------------------------------------------------------
    def observe(self, frame: Frame) -> None:
        """Record one perception frame (detections outside the workspace dropped as outliers). Raises
        ``ValueError`` when ``frame.t`` does not come after the previous frame's time."""
        self.inputs.check_time(frame.t)
        frame = self.memory.admit(frame)
        self.inputs.add(frame, self.memory.record(frame))

    def propose(self, state: ParticleState, dt: float, rng: np.random.Generator) -> Proposal:
        """The particles' motion before physics for an update at the newest frame's time, ``dt``
        seconds after the previous one (:meth:`move`), and the worlds' input for it."""
        frame = self.inputs.frame
        detected, cameras = self.inputs.take()
        perceived = self.memory.perceived(frame.t)
        move = self.move(state, frame, detected, perceived, dt, rng, cameras)
        return Proposal(frame.t, dt, frame, detected, perceived, cameras, move, self.batch(move, state))

    def weigh(self, state: ParticleState, p: Proposal, out: BatchOutput, rng: np.random.Generator) -> Weighed:
        """After physics (``out``, exploded particles already reset by the pool): the particles settled
        (:meth:`settle`), the evidence and the new log-weights (:meth:`log_weight`). When every particle
        has zero weight the detected objects are re-seeded from perception (:meth:`reseed`, in the
        settled arrays) and the log-weights are all zero."""
        settled = self.settle(state, p.move, out, p.t, p.dt, p.detected, p.perceived)
        evidence = self.evidence(p.move, settled, out, p.frame, p.detected, p.perceived, state.unseen_in_view)
        logw = self.log_weight(state.log_weights, evidence)
        if not np.any(np.isfinite(logw)):
            self.recoveries += 1
            log.warning("t=%.3f: every particle has zero weight; re-seeding detected objects from perception", p.t)
            self.reseed(settled.poses, settled.velocities, p.detected, rng)
            logw = np.zeros(self.K)
        self.weighed |= p.detected | np.any(evidence.visible >= self.config.visibility_threshold, axis=0)
        return Weighed(settled, evidence, logw)

    def commit(self, state: ParticleState, p: Proposal, w: Weighed, rng: np.random.Generator) -> ParticleState:
        """The particles after the update (the largest finite log-weight made 0), their events recorded;
        the perception memory closes the update."""
        thr, settled = self.config.visibility_threshold, w.settled
        hidden = places_after_update(state, w.evidence, settled, p.t, rng, thr)
        new = state.after_update(p.move, settled, w.log_weights, held_unseen_in_view(w.evidence, thr), hidden,
                                 settled.modes == FREE)
        self.memory.end_tick(p.perceived, p.detected, settled.tick_vel)
        record_event_times(new.event_t, settled.codes, p.t, settled.times, new.push_decided)
        return new

    def particles_needed(self, settled: Settled, weights: np.ndarray) -> int:
        """How many particles the belief of ``settled`` under ``weights (K,)`` needs
        (:func:`~estimator.adaptive.particles_needed`, over the known dynamic objects)."""
        return particles_needed(settled.poses, settled.modes, weights, self.known & self.dynamic,
                                self.config.adaptive)[0]

    def before_resampling(self, state: ParticleState, settled: Settled, perceived: np.ndarray,
                          weights: np.ndarray) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """What resampling needs from the model: the objects ``(M,)`` each particle keeps its own
        values of (hidden, known and dynamic, weighed by nothing since the last resampling,
        :meth:`unweighable`: the weights are about other objects, and resampling them too would only
        lose their spread; see :meth:`~estimator.state.ParticleState.take`), and the jitter kernels of
        the other hidden objects (:meth:`regularisation_kernels`)."""
        hidden = self.known & self.dynamic & ~perceived
        own = hidden & ~self.weighed & self.unweighable(settled)
        return own, self.regularisation_kernels(state.poses, weights, hidden & ~own)

    def after_resampling(self, state: ParticleState, kernels: dict[int, np.ndarray],
                         rng: np.random.Generator) -> None:
        """In place on the resampled ``state`` (its K is the new count): regularisation
        (:meth:`regularise`); nothing is weighed since."""
        self.K = len(state.log_weights)
        self.weighed = np.zeros(self.M, dtype=bool)
        self.regularise(state, kernels, rng)

    # -- the prior ------------------------------------------------------------------------------------
    def initial_state(self, rng: np.random.Generator) -> ParticleState:
        """K particles at the scene's poses, with physical parameters drawn from their priors and the
        positions of known dynamic objects perturbed horizontally by ``position_std``."""
        K, M, nz = self.K, self.M, self.config.noise
        poses = np.repeat(initial_poses(self.scene)[0][None], K, axis=0)
        base = self.base_params
        params = np.repeat(base[None], K, axis=0)
        dyn = np.flatnonzero(self.dynamic)
        ranges = [nz.friction_range, nz.rolling_friction_range, nz.spinning_friction_range,
                  nz.restitution_range]
        for col, r in enumerate(ranges):
            if r is not None:
                params[:, dyn, col] = rng.uniform(r[0], r[1], size=(K, len(dyn)))
        if nz.rolling_friction_range is None and nz.rolling_friction_scale is not None:
            rollers = np.flatnonzero(self.dynamic & self.round & (base[:, 1] > 0))
            if len(rollers):
                lo, hi = np.log(nz.rolling_friction_scale)
                params[:, rollers, 1] = base[rollers, 1] * np.exp(rng.uniform(lo, hi, size=(K, len(rollers))))
        if nz.mass_scale_range is not None:
            lo, hi = nz.mass_scale_range
            params[:, dyn, 4] = base[dyn, 4] * rng.uniform(lo, hi, size=(K, len(dyn)))
        self.perturbed = np.any(params != params[:1], axis=0) | (np.ptp(params, axis=0) > 0)  # (M, 5)
        if nz.position_std > 0:  # horizontally: pushed into its support or dropped onto it, an object
            known_dyn = np.flatnonzero(self.dynamic & self.known)  # starts by bouncing (a duck tips over)
            poses[:, known_dyn, :2] += rng.normal(0, nz.position_std, (K, len(known_dyn), 2))
            self._just_initialised[known_dyn] = True
        return ParticleState(poses=poses, velocities=np.zeros((K, M, 6)), params=params,
                             modes=np.zeros((K, M), dtype=np.int8), log_weights=np.zeros(K),
                             on_top=np.zeros((K, M, M + 1), dtype=bool), is_in=np.zeros((K, M, M), dtype=bool),
                             event_t=np.full((K, M, N_ACTIONS), -np.inf), supported=np.zeros((K, M), dtype=bool),
                             last_motion=np.zeros((K, M)), jolted=np.zeros((K, M), dtype=bool),
                             unseen_in_view=np.zeros((K, M), dtype=np.int32), hold_error=np.zeros((K, M, 3)),
                             let_go_unseen=np.full((K, M), -np.inf), hidden_at=np.zeros((K, M, 3)),
                             hidden_t=np.full((K, M), -np.inf), hidden_n=np.zeros((K, M), dtype=np.int32),
                             down_at=np.zeros((K, M, 3)), down_t=np.full((K, M), -np.inf),
                             rest_at=np.zeros((K, M, 3)), rest_t=np.full((K, M), -np.inf),
                             push_decided=np.full((K, M), -np.inf), holds=empty_holds((K, M)),
                             jitter=np.zeros((K, M, 3)), push_grip=np.full((K, M), np.nan))

    # -- the move -------------------------------------------------------------------------------------
    def move(self, state: ParticleState, frame: Frame, detected: np.ndarray, perceived: np.ndarray,
             dt: float, rng: np.random.Generator, cameras: tuple | None = None) -> Move:
        """Everything before physics, for ``dt`` seconds since the last update: ``detected (M,)`` since
        the last update, ``perceived (M,)`` now; ``cameras``: the cameras (:class:`CameraSpec`) that
        took the frames since the last update (None: the scene's camera only). The mechanisms' hooks
        (:mod:`estimator.mechanisms`) run phase by phase on a :class:`~estimator.mechanisms.Draft`;
        then what physics checks and reports. Updates :attr:`known` and the memory's velocities."""
        cfg, mem, K, M = self.config, self.memory, self.K, self.M
        poses, vel = state.poses.copy(), state.velocities.copy()
        newly_known = perceived & ~self.known
        no = np.zeros(M, dtype=bool)
        fresh = detected if cfg.fresh_checks else perceived
        u = Draft(state=state, frame=frame, detected=detected, perceived=perceived, dt=dt, rng=rng, cameras=cameras,
                  # a finite difference across a jump or a gap is no velocity; one across a reasoning
                  # period of continuous tracking is (moving_teleports: an object tracked in motion keeps moving)
                  tick_vel=mem.tick_velocity(), following=mem.following_hand(frame),
                  far=self._out_of_reach(frame, detected), poses=poses, vel=vel, prev_modes=state.modes.copy(),
                  predicted=poses.copy(),  # before teleports: what each particle expected
                  jitter=np.zeros((K, M, 3)), newly_known=newly_known,
                  tele=perceived & (~mem.perceived_prev | mem.jumped() | newly_known),  # teleports, first sightings
                  moving=no, falling=no, spinning=no, cover_t=np.full((K, M), np.nan), proposal=np.zeros(K),
                  # at rest in the particle (on a support, slower than rest_speed) before this update
                  resting=state.supported & (np.linalg.norm(state.velocities[..., :3], axis=-1) < cfg.noise.rest_speed),
                  check=np.broadcast_to(perceived & fresh, (K, M)).copy(),
                  jolted=np.zeros((K, M), dtype=bool), let_go=state.let_go_unseen.copy(),
                  target=poses.copy(), target_vel=np.zeros((K, M, 6)), hold_error=state.hold_error)
        for phase in PHASES:
            for hook in self._hooks[phase]:
                hook(u)
        if u.modes is None:  # no mechanism releases anything
            u.modes, u.release_codes = u.prev_modes.copy(), np.zeros((K, M), dtype=np.int8)
        # what physics checks and reports
        vis_query = self.known & self.dynamic & ~detected
        has_camera = self.scene.camera is not None if cameras is None else len(cameras) > 0
        if not (cfg.negative_evidence and has_camera):
            vis_query = np.zeros(M, dtype=bool)
        placed = u.tele | self._just_initialised
        self._just_initialised = np.zeros(M, dtype=bool)
        depen = (np.broadcast_to(placed & (cfg.noise.position_std > 0), (K, M)) | u.jolted
                 | state.jolted | u.cover) & (u.modes == FREE)
        set_moving = u.set_moving if u.set_moving is not None and u.set_moving.any() else None
        return Move(u.poses, u.vel, u.predicted, u.prev_modes, u.modes, u.release_codes, u.tele, u.target, u.target_vel,
                    u.check, depen, vis_query, u.hold_error, u.let_go, cameras, u.cover_t, u.proposal, u.nudged,
                    u.jitter, u.far, u.fall, u.detections, set_moving, u.speed_check, u.grip)

    def unheld_overrides(self, move: Move, out: BatchOutput, supported: np.ndarray, seen: np.ndarray,
                         tick_vel: np.ndarray) -> np.ndarray | None:
        """Entries ``(K, M)`` that physics switched to HELD in this update (free before, they diverged
        from their detection: Algorithm 1's override) of objects ``seen (M,)`` now moving along their
        support (tick velocity ``(M, 3)``, :func:`~estimator.motion.rolled_along`), ``supported (K,
        M)`` in their particle, that no tracked hand can reach (``Move.out_of_reach``; every object
        when no hand is tracked): a Pick needs an agent within reach, so they stay free (None: none;
        never in paper mode)."""
        if not self.config.moving_teleports:
            return None
        unreached = np.ones(self.M, dtype=bool) if move.out_of_reach is None else move.out_of_reach
        cand = (seen & unreached & self.dynamic & rolled_along(tick_vel)
                & moving_beyond_noise(self.memory, self.config.noise.position_std))
        if not np.any(cand):
            return None
        out_mask = (move.modes == FREE) & (out.modes == HELD) & cand[None, :] & supported
        return out_mask if np.any(out_mask) else None

    def roll_released(self, vel: np.ndarray, released: np.ndarray, supported: np.ndarray) -> None:
        """In place on ``vel (K, M, 6)``: balls let go now (``released (K, M)``) on a support
        (``supported (K, M)``) or just after they were seen rolling along one (off an edge) roll at
        their velocity (:func:`~estimator.motion.roll_released`)."""
        rolled = released & (supported | rolled_along(self.memory.previous_tick_velocity())[None, :])
        if np.any(rolled):
            roll_released(vel, rolled, self.ball_radius)

    def batch(self, move: Move, state: ParticleState) -> BatchInput:
        """The pool's input for ``move`` (which entries to load, and which a world produced at rest,
        the pool's cache decides: :meth:`~estimator.pool.WorldPool.advance`)."""
        return BatchInput(poses=move.poses, velocities=move.velocities, params=state.params, modes=move.modes,
                          check=move.check, target=move.target, target_vel=move.target_vel, contents=state.is_in,
                          depenetrate=move.depenetrate, vis_query=move.vis_query)

    # -- after physics --------------------------------------------------------------------------------
    def settle(self, state: ParticleState, move: Move, out: BatchOutput, t: float, dt: float,
               detected: np.ndarray, perceived: np.ndarray) -> Settled:
        """Relations of the particles ``out`` gives (their exploded ones already reset); Place: a held
        object perceived at rest on a support is let go; Release in view: a held object perceived
        falling (fast, or accelerating down with nothing under it) was let go; the events."""
        hr, cfg, mem = self.config.reasoner, self.config, self.memory
        for mechanism in self.mechanisms:
            out.poses = mechanism.after_physics(out.poses, out.aabbs)
        new_modes = out.modes.copy()  # out.modes stays what physics made (Evidence.diverged)
        valid = np.broadcast_to(self.known, (self.K, self.M))
        on_top, is_in, supported = relations_and_support(
            out.aabbs, valid, static=self.static, floor=self.scene.floor, config=cfg.relations,
            previous=(state.on_top, state.is_in), z_gap=hr.place_gap, hollow=self.hollow)
        rested = mem.at_rest(t)
        vel = mem.tick_velocity()
        accel = mem.vertical_acceleration(vel, dt)
        # fast enough, it is let go whatever is under it; accelerating down, only if nothing is
        falling = (vel[:, 2] < -hr.release_speed)[None, :] | (
            ((accel < -hr.release_accel) & (vel[:, 2] < -RELEASE_DOWN_SPEED))[None, :] & ~supported)
        held_seen = (new_modes == HELD) & perceived[None, :]
        after_physics = out.modes
        put_down = held_seen & rested[None, :] & supported
        if np.any(put_down) and self.episode_rule.lift < hr.place_gap:
            # held still more than `lift` above its support (a box paused 2 cm up): let go, it would
            # drop that far and be held again by the episode rule (update_events); it is held
            put_down &= supported_mask(out.aabbs, is_in, valid, static=self.static, floor=self.scene.floor,
                                       z_gap=self.episode_rule.lift, config=cfg.relations)
        new_modes[put_down | (held_seen & falling)] = FREE
        # physics could not follow an object seen moving along its support, but no tracked hand can
        # reach it: no agent holds it; it goes on free at its perceived velocity (overridden in motion)
        unheld = self.unheld_overrides(move, out, supported, detected & perceived, vel)
        if unheld is not None:
            new_modes[unheld] = FREE
            after_physics = np.where(unheld, FREE, after_physics).astype(after_physics.dtype)
        # the switches read as actions (actions.episodes): a Pick dated when the object started
        # moving, a Place once physics confirms it (dated when it came to rest), a Push if unlifted
        rule, onset = self.episode_rule, mem.moving_since
        # what is in or on an object held, or perceived moving along its support (a pushed box not
        # yet held in this particle), is carried: whoever moves it moves its support
        carrier = np.where((mem.shifted(CARRIER_SHIFT) & perceived)[None, :], HELD, after_physics)
        silent = carried(state.is_in, state.on_top, carrier)
        if move.out_of_reach is not None:  # hands are tracked, none within reach of it: an action needs
            silent = silent | move.out_of_reach[None, :]  # an agent; its particle's physics moved it
        acted = np.isfinite(state.event_t).any(axis=-1)  # an event before this update
        quiet = silent | acted
        if cfg.still_unacted:  # seen still, and at rest in its particle before or on a support where
            # it is seen: no one moved it, its particle's physics did (no events); one held still in
            # the air is held
            still = detected & self.dynamic & np.isnan(onset) & np.isfinite(mem.still_position[:, 0])
            silent = silent | (still[None, :] & (np.isfinite(state.holds[..., REF_Z]) | supported))
        # objects let go behind cover were let go back then, out of view (release_t)
        release_codes = dropped_behind_cover(move.release_codes, move.behind_cover, move.poses, out.poses, out.aabbs,
                                             self.scene.floor)
        ev = update_events(
            state.holds, acted, silent,
            move.modes, after_physics, new_modes, release_codes, supported,
            supported & (np.linalg.norm(out.velocities[..., :3], axis=-1) < rule.rest_speed), move.poses[..., 2],
            out.poses[..., 2], self._seen_z(t, detected),
            np.where((onset >= t - cfg.event_window) & (onset <= t), onset, t), t, rule, let_go_t=t - hr.place_dwell,
            release_t=move.cover_t, rolled_off=None if move.fall is None else move.fall.mask[None, :])
        # taken in hand while still seen at rest, then seen to start moving: the Pick is that start
        codes, times, holds = late_picks(ev.codes, ev.times, ev.holds, ev.modes == HELD, onset, quiet,
                                         t - cfg.event_window, t)
        set_moving = move.set_moving
        if unheld is not None:  # those at rest in their particle before: set moving by an agent nobody tracks
            at_rest = np.linalg.norm(state.velocities[..., :3], axis=-1) < rule.rest_speed
            fresh = np.isfinite(onset) & (onset >= t - dt - hr.place_dwell)  # it just started moving, not
            started = unheld & at_rest & (move.previous_modes == FREE) & fresh[None, :]  # a drift of physics
            set_moving = started if set_moving is None else (set_moving | started)
        if set_moving is not None:  # set moving by an agent nobody tracks: a Push when it began
            pushed = set_moving & (ev.modes == FREE) & (codes == 0)
            if np.any(pushed):
                began = np.where(np.isfinite(onset), onset, t)[None, :]
                codes = np.where(pushed, PUSH, codes).astype(codes.dtype)
                times = np.where(pushed, np.broadcast_to(began, times.shape), times)
        velocities = out.velocities
        if unheld is not None:  # at the velocity it is seen moving at, rolling if it is a ball
            velocities = velocities.copy()
            kk, mm = np.nonzero(unheld)
            velocities[kk, mm] = 0.0
            velocities[kk, mm, :2] = mem.perc_vel[mm, :2]
            self.roll_released(velocities, unheld, np.ones_like(unheld))
        released = (after_physics == HELD) & (ev.modes == FREE)
        if np.any(released):
            velocities = velocities.copy()
            self.roll_released(velocities, released, supported)
            # let go falling, off an edge (move.fall) or from a hand (the Release rule): at the speed
            # of the free fall through its last detections now, not the hand's (a ball seen falling
            # for 0.2 s falls at 2 m/s; let go at rest, it would land an update late)
            fell = released & (falling | (False if move.fall is None else move.fall.mask[None, :]))
            if cfg.moving_teleports and np.any(fell):
                vz_now = mem.free_fall((t,), cfg.physics.gravity, cfg.noise.position_std)[1][0]
                fell &= np.isfinite(vz_now)[None, :]
                velocities[..., 2] = np.where(fell, vz_now[None, :], velocities[..., 2])
        return Settled(out.poses, velocities, ev.modes, on_top, is_in, supported, codes, vel, holds, times)

    def _seen_z(self, t: float, detected: np.ndarray) -> np.ndarray:
        """Height ``(M,)`` (m) where each object detected since the last update is seen now: the lower
        of its latest detection and their mean over ``place_dwell`` (noise averaged, and an object
        that just fell is seen where it fell); NaN where not detected."""
        mean = self.memory.mean_positions(t, self.config.reasoner.place_dwell)[:, 2]
        return np.where(detected, np.fmin(self.memory.last_pose[:, 2], mean), np.nan)

    # -- the weights ----------------------------------------------------------------------------------
    def evidence(self, move: Move, settled: Settled, out: BatchOutput, frame: Frame, detected: np.ndarray,
                 perceived: np.ndarray, unseen_in_view: np.ndarray) -> Evidence:
        """What the log-weight terms read for this update (``unseen_in_view (K, M)``: the particles'
        counts before it, see :class:`~estimator.state.ParticleState`)."""
        mem = self.memory
        carried = mem.hand_travel() > self.config.priors.carry_distance
        # an object its hand has not moved since it was last detected there is not hidden by that hand
        seen_in_hand = mem.following_hand(frame) & ~carried
        visible = self.behind_hands(out.visible, settled.poses, out.aabbs, frame, move.cameras,
                                    move.vis_query & ~seen_in_hand)
        return Evidence(poses=settled.poses, predicted=move.predicted, previous_modes=move.previous_modes,
                        modes=settled.modes, detected=detected & self.dynamic, teleported=move.teleported,
                        perceived=perceived, detected_poses=mem.last_pose if move.detections is None else move.detections,
                        has_orientation=mem.last_has_orientation, detection_std=mem.last_std,
                        visible=visible, queried=move.vis_query,
                        in_tracked_hand=mem.following_hand(frame), finite=out.finite,
                        unseen_in_view=unseen_in_view,
                        fell_unseen=(settled.modes == FREE)
                        & (frame.t - move.let_go_unseen < self.config.reasoner.t_perceived - 1e-9),
                        proposal_log_weight=move.proposal_log_weight, fused=move.fused,
                        out_of_reach=move.out_of_reach, diverged=diverged_by(move, out),
                        fell=None if move.fall is None else move.fall.mask,
                        carried=carried,
                        **({} if move.speed_check is None else dict(
                            velocity_check=move.speed_check[0] & (settled.modes == FREE),
                            predicted_velocity=move.speed_check[1], seen_velocity=move.speed_check[2],
                            seen_velocity_std=move.speed_check[3])))

    def behind_hands(self, visible: np.ndarray, poses: np.ndarray, aabbs: np.ndarray, frame: Frame,
                     cameras: tuple | None, queried: np.ndarray) -> np.ndarray:
        """``visible (K, M)`` with what the tracked hands of ``frame`` hide taken out: each queried
        object ``queried (M,)``, a ball of its box's mean half extent (``aabbs (K, M, 2, 3)``) at its
        position in ``poses (K, M, 7)``, keeps ``1 - share`` of its visible fraction, ``share`` being
        the part of its disk a hand (``NoiseConfig.hand_radius``) covers from the camera that sees
        the most of it (:func:`~physics.visibility.sphere_occlusion`; ``cameras``: those of the
        update, None: the scene's). The worlds hold no hands. (The caller leaves out an object whose
        hand has not moved since it was last detected in it: it was seen there, so its hand does
        not hide it.)"""
        r = self.config.noise.hand_radius
        if not frame.hands or r <= 0 or not np.any(queried):
            return visible
        cams = [self.scene.camera] if cameras is None else list(cameras)
        cams = [c for c in cams if c is not None]
        if not cams:
            return visible
        idx = np.flatnonzero(queried)
        hands = np.array([np.asarray(h, dtype=float) for h in frame.hands.values()])
        radii = 0.5 * np.mean(aabbs[:, idx, 1] - aabbs[:, idx, 0], axis=-1)
        shares = [sphere_occlusion(np.asarray(c.position, float), poses[:, idx, :3], radii, hands, r) for c in cams]
        out = visible.copy()
        out[:, idx] = visible[:, idx] * (1.0 - np.min(shares, axis=0))
        return out

    def _out_of_reach(self, frame: Frame, detected: np.ndarray) -> np.ndarray | None:
        """Dynamic objects ``(M,)`` detected since the last update whose latest detection lies farther
        than :data:`~estimator.perception_memory.HAND_RADIUS` from every hand tracked in ``frame``;
        None when no hand is tracked in it or hands are not followed."""
        if not self.config.follow_hands:
            return None
        return out_of_reach(self.memory.last_pose[:, :3], frame.hands, detected & self.dynamic, HAND_RADIUS)

    def log_weight(self, previous: np.ndarray, ev: Evidence) -> np.ndarray:
        """New log-weights ``(K,)``: ``previous (K,)`` plus every term of :attr:`terms` (one particle
        has nothing to be weighed against: no terms), and -inf for exploded particles."""
        logw = add_terms(previous, self.terms, ev) if self.K > 1 else previous.copy()
        logw = logw + exploded_log_likelihood(ev.finite)
        self.note_surprise(ev, logw)
        return logw

    def note_surprise(self, ev: Evidence, logw: np.ndarray) -> None:
        """Track, per object, how far the perceived velocity of an object moving on its support is
        from what the particles' physics predicted (``Evidence.velocity_check``), in units of its
        standard deviation, under the new weights ``logw (K,)``: an exponential average (half of the
        old, half of the new) of the squared mean innovation (:attr:`surprise` ``(M,)``). Calibrated,
        it stays near 1; a value over :data:`SURPRISE` says every particle gets the object's motion
        wrong the same way (its friction is outside what the particles hold), and its parameters
        are widened at the next resampling (:meth:`regularise`)."""
        if ev.velocity_check is None or self.K < 2 or not np.any(np.isfinite(logw)):
            return
        w, _ = normalise_log_weights(logw)
        nz = self.config.noise
        std = np.sqrt(np.asarray(ev.seen_velocity_std, float) ** 2 + nz.velocity_slack ** 2)
        for m in np.flatnonzero(ev.velocity_check.any(axis=0)).tolist():
            rows = ev.velocity_check[:, m]
            wm = w * rows
            if wm.sum() <= 0:
                continue
            d = (ev.seen_velocity[m] - (wm[:, None] * ev.predicted_velocity[:, m]).sum(axis=0) / wm.sum()) / std[m]
            self.surprise[m] = 0.5 * self.surprise[m] + 0.5 * float(d @ d) / 2.0

    def reseed(self, poses: np.ndarray, vel: np.ndarray, detected: np.ndarray, rng: np.random.Generator) -> None:
        """Recovery when every particle has zero weight, in place: detected objects ``(M,)`` are put at
        their perceived position (plus ``position_std`` noise), at rest."""
        idx = np.flatnonzero(detected & self.dynamic)
        if len(idx):
            poses[:, idx, :3] = self.memory.last_pose[idx, :3]
            if self.config.noise.position_std > 0:
                poses[:, idx, :3] += rng.normal(0.0, self.config.noise.position_std, (self.K, len(idx), 3))
            vel[:, idx] = 0.0

    # -- after resampling -----------------------------------------------------------------------------
    def unweighable(self, settled: Settled) -> np.ndarray:
        """Objects ``(M,)`` whose particles physics cannot tell apart by what else happens: free and at
        rest on a support in every particle, and no other object on or in them in any particle."""
        at_rest = settled.supported & slow(settled.velocities)
        parent = settled.on_top[..., :self.M].any(axis=1) | settled.is_in.any(axis=1)
        return np.all((settled.modes == FREE) & at_rest & ~parent, axis=0)

    def regularisation_kernels(self, poses: np.ndarray, weights: np.ndarray,
                               hidden: np.ndarray) -> dict[int, np.ndarray]:
        """The jitter kernels of the hidden objects ``hidden (M,)`` after resampling
        (:func:`~estimator.noise.regularisation_kernels`), from their spread under ``weights (K,)``
        mixed with equal weights in proportion ``1 - ESS / K``: weights that leave few particles
        are mostly about other objects (a cube picked up in plain view can give one particle all the
        weight), and a kernel sized by them alone would leave a hidden object that particle's one
        value. What the weights do say about a hidden object (negative evidence) they say again at
        the next update to the jittered copies."""
        nz = self.config.noise
        K = len(weights)
        share = effective_sample_size(weights) / K
        mixed = share * weights + (1.0 - share) / K
        return regularisation_kernels(poses, mixed, hidden, nz.regularisation, nz.max_jitter_std)

    def regularise(self, state: ParticleState, kernels: dict[int, np.ndarray], rng: np.random.Generator) -> None:
        """In place, after resampling: jitter the free copies of each hidden object with its kernel (a
        regularised particle filter: copies of one particle must not leave a hidden object with no
        spread; a jitter into static geometry stops at its surface, ``static_clip``), then the
        physical parameters (Liu-West shrinkage, :func:`shrink_params`)."""
        for m, chol in kernels.items():
            free = state.modes[:, m] == FREE
            noise = rng.standard_normal((self.K, 3)) @ chol.T
            before = state.poses[free, m].copy()
            state.poses[free, m, :3] += noise[free]
            state.jolted[free, m] = True
            if self.geometry is not None and np.any(free):  # not into the table or under the floor
                state.poses[free, m] = self.geometry.clip(m, before, state.poses[free, m])[0]
        nz = self.config.noise
        if nz.param_jitter > 0:
            dyn = np.flatnonzero(self.dynamic)
            floor = np.full((len(dyn), 5), nz.param_floor)
            floor[self.surprise[dyn] > SURPRISE, :2] = nz.param_widen  # frictions: surprised by its motion
            state.params[:, dyn] = shrink_params(state.params[:, dyn], nz.param_jitter, self.param_bounds, rng,
                                                 floor, self.perturbed[dyn])
