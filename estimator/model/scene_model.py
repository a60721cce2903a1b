"""The scene model: how a particle moves between two updates, and how it is weighed.

K particles, M objects; positions in metres, quaternions ``(x, y, z, w)``, times in seconds. The
model owns the perception memory (:class:`~estimator.model.perception_memory.PerceptionMemory`) and
what arrived since the last update (:class:`~estimator.model.inputs.StepInputs`), and knows the
scene and the configuration; the particle filter (:class:`~estimator.filter.SceneEstimator`) owns
the particles and the worlds and calls, at each update, its narrow contract:

1. :meth:`SceneModel.observe` for every frame;
2. :meth:`SceneModel.propose`: the motion before physics (:meth:`SceneModel.move`: the hooks of the
   mechanisms, :mod:`estimator.model.mechanisms`, phase by phase) and the worlds' input (physics
   itself is the pool's, Alg. 1);
3. :meth:`SceneModel.weigh`: the particles after physics (:mod:`estimator.model.settle`: relations,
   Place and Release in view, the update's events) and their new log-weights
   (:mod:`estimator.model.weighing`: the terms of :mod:`estimator.model.likelihood`);
4. :meth:`SceneModel.commit`: the particles after the update;
5. around resampling, :meth:`SceneModel.before_resampling` and :meth:`SceneModel.after_resampling`
   (:mod:`estimator.model.regularisation`: kernel jitter of hidden free objects and Liu-West
   shrinkage of the physical parameters).
"""
from __future__ import annotations

import logging
from time import perf_counter

import numpy as np

from actions.episodes import EpisodeRule
from actions.events import record_event_times
from actions.modes import is_free
from physics.penetration import StaticGeometry
from physics.scene import Scene

from ..adaptive import particles_needed
from ..config import EstimatorConfig
from ..observations import Frame
from ..state import ARRAYS, ParticleState
from ..worlds.pool import BatchInput, BatchOutput
from . import regularisation, weighing
from . import settle as settling
from .hand_memory import HAND_RADIUS
from .inputs import StepInputs
from .mechanisms import PHASES, Draft, Mechanism, mechanisms_for
from .motion import out_of_reach, roll_released, rolled_along
from .noise import Kernel, centred_normal
from .params import param_bounds, world_params
from .perception_memory import PerceptionMemory
from .prior import REACH_SIGMAS, rest_prior
from .step import Move, Proposal, Settled, Weighed
from .terms import Evidence, LogWeightTerm, held_unseen_in_view

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


class SceneModel:
    """How the particles of ``scene`` move and are weighed (see the module docstring).

    Args:
        scene: the scene. config: the estimator's configuration.
        base_params: ``(M, 5)`` the scene's physical parameters (the worlds' initial ones).
        memory: the perception memory the model reads (default: one built for ``scene`` and ``config``).
        mechanisms: ``model -> list[Mechanism]``, the mechanisms it is built from, in the order their
            hooks run (default :func:`~estimator.model.mechanisms.mechanisms_for`; a caller adds its
            own with ``lambda model: mechanisms_for(model) + [Mine(model)]``).

    ``known (M,)``: objects with an initial pose or perceived since; ``prior (M, 7)``: the poses the
    particles start from (the scene's, or where its objects rest: ``config.rest_prior``); ``mechanisms``: the list;
    ``terms``: the log-weight terms; ``seconds``: the wall time (s) spent so far in each part of the
    model, each mechanism's hook by ``"<class>.<phase>"``, and ``"settle"``, ``"weigh"``, ``"commit"``
    (``bench --breakdown`` reports it per update).
    """

    def __init__(self, scene: Scene, config: EstimatorConfig, base_params: np.ndarray,
                 memory: PerceptionMemory | None = None, mechanisms=None):
        self.scene = scene
        self.config = config
        given, self.known = initial_poses(scene)
        reach = REACH_SIGMAS * np.array([config.noise.position_std, config.noise.orientation_std])
        # the poses the particles start from (prior.rest_prior: where the objects come to rest), and
        # the objects resting flat on static bodies alone there (placed asleep, regularisation.placed_at_rest)
        self.flat = np.zeros(len(scene.objects), dtype=bool)
        self.prior = given
        if config.rest_prior:
            self.prior, _, self.flat = rest_prior(scene, given, self.known, config.physics, *reach)
        self.memory = memory if memory is not None else PerceptionMemory(
            scene, self.prior, config.reasoner, config.follow_hands,
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
        self.base_params = base_params
        self.param_bounds = param_bounds(config)
        self.perturbed = np.zeros((self.M, 5), dtype=bool)  # parameters the prior spreads (initial_state)
        self.surprise = np.zeros(self.M)  # how far the objects' motion is from the particles' (the velocity evidence's after_weighing)
        hr = config.reasoner
        self.episode_rule = EpisodeRule(hr.push_lift, hr.push_smoothing, hr.place_wait)
        self._just_initialised = np.zeros(self.M, dtype=bool)
        self._placing = False  # the first update after initial_state: objects placed at rest are found
        self._radii: np.ndarray | None = None  # (M,) m: bounding radii for carried_at_rest
        # the static bodies, to stop paths at their surfaces (config.static_clip)
        solid = bool(np.any(self.static)) or scene.floor
        self.geometry = StaticGeometry(scene, config.physics) if config.static_clip and solid else None
        self.mechanisms: list[Mechanism] = (mechanisms or mechanisms_for)(self)
        # a hook is a method of the mechanism's class named by its phase (not any attribute so named)
        self._hooks = {phase: [(f"{type(m).__name__}.{phase}", getattr(m, phase)) for m in self.mechanisms
                               if callable(getattr(type(m), phase, None))] for phase in PHASES}
        # wall time (s) spent in each part of the model so far: each hook, and "settle", "weigh", "commit"
        self.seconds: dict[str, float] = {name: 0.0 for hooks in self._hooks.values() for name, _ in hooks}
        self.seconds.update(settle=0.0, weigh=0.0, commit=0.0)
        self.terms: tuple[LogWeightTerm, ...] = weighing.log_weight_terms(self)  # the mechanisms' among them

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
        return Proposal(frame.t, dt, frame, detected, perceived, cameras, move, self.batch(move, state),
                        moving_targets=self.config.moving_teleports)

    def weigh(self, state: ParticleState, p: Proposal, out: BatchOutput, rng: np.random.Generator) -> Weighed:
        """After physics (``out``, exploded particles already reset by the pool): the particles settled
        (:meth:`settle`), the evidence and the new log-weights (:meth:`log_weight`). When every particle
        has zero weight the detected objects are re-seeded from perception (:meth:`reseed`, in the
        settled arrays) and the log-weights are all zero."""
        t0 = perf_counter()
        settled = self.settle(state, p.move, out, p.t, p.dt, p.detected, p.perceived)
        t1 = perf_counter()
        evidence = self.evidence(p.move, settled, out, p.frame, p.detected, p.perceived, state.unseen_in_view)
        logw = self.log_weight(state.log_weights, evidence)
        self.seconds["settle"] += t1 - t0
        self.seconds["weigh"] += perf_counter() - t1
        if not np.any(np.isfinite(logw)):
            self.recoveries += 1
            log.warning("t=%.3f: every particle has zero weight; re-seeding detected objects from perception", p.t)
            regularisation.reseed(self, settled.poses, settled.velocities, p.detected, rng)
            logw = np.zeros(self.K)
        self.weighed |= p.detected | np.any(evidence.visible >= self.config.visibility_threshold, axis=0)
        return Weighed(settled, evidence, logw)

    def commit(self, state: ParticleState, p: Proposal, w: Weighed, rng: np.random.Generator) -> ParticleState:
        """The particles after the update (the largest finite log-weight made 0), their events recorded;
        the perception memory closes the update."""
        thr, settled = self.config.visibility_threshold, w.settled
        t0 = perf_counter()
        declared = {}
        for mechanism in self.mechanisms:  # each one's arrays after the update
            declared.update(mechanism.commit(state, p, w, rng))
        new = state.after_update(p.move, settled, w.log_weights, held_unseen_in_view(w.evidence, thr),
                                 is_free(settled.modes), **declared)
        self.memory.end_tick(p.perceived, p.detected, settled.tick_vel)
        record_event_times(new.event_t, settled.codes, p.t, settled.times, new.push_decided)
        self.seconds["commit"] += perf_counter() - t0
        return new

    def particles_needed(self, settled: Settled, weights: np.ndarray) -> int:
        """How many particles the belief of ``settled`` under ``weights (K,)`` needs
        (:func:`~estimator.adaptive.particles_needed`, over the known dynamic objects)."""
        return particles_needed(settled.poses, settled.modes, weights, self.known & self.dynamic,
                                self.config.adaptive)[0]

    def before_resampling(self, state: ParticleState, settled: Settled, perceived: np.ndarray,
                          weights: np.ndarray) -> tuple[np.ndarray, dict[int, Kernel]]:
        """What resampling needs from the model: the objects ``(M,)`` each particle keeps its own
        values of (hidden, known and dynamic, weighed by nothing since the last resampling,
        :meth:`unweighable`: the weights are about other objects, and resampling them too would only
        lose their spread; see :meth:`~estimator.state.ParticleState.take`), and the jitter kernels of
        the other hidden objects (:meth:`regularisation_kernels`)."""
        hidden = self.known & self.dynamic & ~perceived
        own = hidden & ~self.weighed & regularisation.unweighable(self, settled)
        return own, regularisation.regularisation_kernels(self, state.poses, weights, hidden & ~own)

    def after_resampling(self, state: ParticleState, kernels: dict[int, Kernel],
                         rng: np.random.Generator, before: ParticleState, own: np.ndarray) -> np.ndarray:
        """In place on the resampled ``state`` (its K is the new count): regularisation
        (:func:`~estimator.model.regularisation.regularise`), and, when K changed, the objects
        ``own (M,)`` each particle kept moved back to where they averaged in ``before``, the state
        before resampling (:func:`~estimator.model.regularisation.own_centres`); nothing is weighed
        since. Returns ``(K, M)`` bool: the entries the jitter only slid along static geometry at
        rest (:func:`~estimator.model.regularisation.slid_at_rest`), for :meth:`carried_at_rest`."""
        self.K = len(state.log_weights)
        self.weighed = np.zeros(self.M, dtype=bool)
        centres = regularisation.own_centres(before, own) if len(before.log_weights) != self.K else None
        return regularisation.regularise(self, state, kernels, rng, centres)

    def after_growth(self, state: ParticleState, kernels: dict[int, Kernel], rng: np.random.Generator,
                     new: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """In place on ``state`` grown by splitting (:func:`~estimator.resampling.split_ancestors`;
        its K is the new count, ``weights (K,)`` its normalised weights): the copies ``new (K,)``
        bool alone are regularised, towards the weighted means (a copy must not leave a hidden
        object, or the physical parameters, with no spread). Nothing was resampled: the weights go
        on, and what they weighed stays weighed. Returns what :meth:`after_resampling` does."""
        self.K = len(state.log_weights)
        return regularisation.regularise(self, state, kernels, rng, None, new, weights)

    def carried_at_rest(self, before: ParticleState, after: ParticleState, ancestors: np.ndarray,
                        own: np.ndarray, boxes: np.ndarray, slid: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray] | None:
        """The entries resampling carried along at rest, for the worlds to load asleep
        (:func:`~estimator.model.regularisation.carried_at_rest`), and those its jitter slid along
        static geometry at rest (``slid (K, M)``, :meth:`after_resampling`'s); ``boxes (M, 2, 3)``:
        the objects' bounding boxes (m) at the scene's poses (the pool's ``scene_boxes``)."""
        if self._radii is None:  # the scene's boxes do not change: the radii once, about the poses they were read at
            self._radii = regularisation.bounding_radii(boxes, initial_poses(self.scene)[0][:, :3])
        out = regularisation.carried_at_rest(self, before, after, ancestors, own, self._radii)
        if slid is None or not slid.any():
            return out
        return (slid if out is None else out[0] | slid), after.poses

    # -- the prior ------------------------------------------------------------------------------------
    def initial_state(self, rng: np.random.Generator) -> ParticleState:
        """K particles at the prior's poses (:attr:`prior`), with physical parameters drawn from their priors and the
        positions of known dynamic objects perturbed horizontally by ``position_std`` (the perturbations centred:
        each object's cloud has the prior's mean, :func:`~estimator.model.noise.centred_normal`)."""
        K, M, nz = self.K, self.M, self.config.noise
        poses = np.repeat(self.prior[None], K, axis=0)
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
            poses[:, known_dyn, :2] += centred_normal(rng, nz.position_std, (K, len(known_dyn), 2))
            self._just_initialised[known_dyn] = True
        self._placing = True
        declared = dict(ARRAYS)
        for mechanism in self.mechanisms:
            declared.update(mechanism.arrays)
        return ParticleState.initial(K, M, dict(poses=poses, velocities=np.zeros((K, M, 6)), params=params,
                                                modes=np.zeros((K, M), dtype=np.int8), log_weights=np.zeros(K)),
                                     declared)

    # -- the move -------------------------------------------------------------------------------------
    def move(self, state: ParticleState, frame: Frame, detected: np.ndarray, perceived: np.ndarray,
             dt: float, rng: np.random.Generator, cameras: tuple | None = None) -> Move:
        """Everything before physics, for ``dt`` seconds since the last update: ``detected (M,)`` since
        the last update, ``perceived (M,)`` now; ``cameras``: the cameras (:class:`CameraSpec`) that
        took the frames since the last update (None: the scene's camera only). The mechanisms' hooks
        (:mod:`estimator.model.mechanisms`) run phase by phase on a :class:`~estimator.model.mechanisms.Draft`;
        then what physics checks and reports. Updates :attr:`known` and the memory's velocities."""
        cfg, mem, K, M = self.config, self.memory, self.K, self.M
        poses, vel = state.poses.copy(), state.velocities.copy()
        newly_known = perceived & ~self.known
        fresh = detected if cfg.fresh_checks else perceived
        jumped = mem.jumped(cfg.noise_aware_jumps)
        # first sightings, within the tracker's noise, of where the scene places an object: its height
        # and orientation are the particle's (its support's), only where it stands is the detection's
        first = ~np.isfinite(mem.seen_at_tick)  # never detected before this update
        level = perceived & self.known & first & ~jumped if cfg.noise_aware_jumps else None
        u = Draft(state=state, frame=frame, detected=detected, perceived=perceived, dt=dt, rng=rng, cameras=cameras,
                  # a finite difference across a jump or a gap is no velocity; one across a reasoning
                  # period of continuous tracking is (moving_teleports: an object tracked in motion keeps moving)
                  tick_vel=mem.tick_velocity(), following=mem.following_hand(frame),
                  far=self._out_of_reach(frame, detected), poses=poses, vel=vel, prev_modes=state.modes.copy(),
                  predicted=poses.copy(),  # before teleports: what each particle expected
                  jitter=np.zeros((K, M, 3)), newly_known=newly_known,
                  tele=perceived & (~mem.perceived_prev | jumped | newly_known), level=level,  # teleports, first sightings
                  moving=np.zeros(M, dtype=bool), falling=np.zeros(M, dtype=bool),
                   cover_t=np.full((K, M), np.nan), proposal=np.zeros(K),
                  # at rest in the particle (on a support, slower than rest_speed) before this update
                  resting=state.supported & (np.linalg.norm(state.velocities[..., :3], axis=-1) < cfg.noise.rest_speed),
                  check=np.broadcast_to(perceived & fresh, (K, M)).copy(),
                  jolted=np.zeros((K, M), dtype=bool), target=poses.copy(), target_vel=np.zeros((K, M, 6)),
                  modes=state.modes.copy(), release_codes=np.zeros((K, M), dtype=np.int8))  # nothing let go yet
        for phase in PHASES:
            for name, hook in self._hooks[phase]:
                t0 = perf_counter()
                hook(u)
                self.seconds[name] += perf_counter() - t0
        # what physics checks and reports
        vis_query = self.known & self.dynamic & ~detected
        has_camera = self.scene.camera is not None if cameras is None else len(cameras) > 0
        if not (cfg.negative_evidence and has_camera):
            vis_query = np.zeros(M, dtype=bool)
        placed = u.tele | self._just_initialised
        self._just_initialised = np.zeros(M, dtype=bool)
        at_rest = None  # where the first placement left objects at rest: loaded asleep, not pushed out
        if self._placing and self.geometry is not None and self.flat.any():
            at_rest = regularisation.placed_at_rest(self, u.poses, u.vel, u.modes, self.flat, self.prior)
        self._placing = False
        depen = (np.broadcast_to(placed & (cfg.noise.position_std > 0), (K, M)) | u.jolted
                 | state.jolted | u.cover) & is_free(u.modes)
        if at_rest is not None:
            depen &= ~at_rest
        set_moving = u.set_moving if u.set_moving is not None and u.set_moving.any() else None
        return Move(poses=u.poses, velocities=u.vel, predicted=u.predicted, previous_modes=u.prev_modes, modes=u.modes,
                    release_codes=u.release_codes, teleported=u.tele, target=u.target, target_vel=u.target_vel,
                    check=u.check, depenetrate=depen, vis_query=vis_query, hold_error=u.hold_error,
                    let_go_unseen=u.let_go, cameras=cameras, cover_t=u.cover_t, proposal_log_weight=u.proposal,
                    fused=u.nudged, jitter=u.jitter, out_of_reach=u.far, fall=u.fall, detections=u.detections,
                    set_moving=set_moving, push_grip=u.grip, placed_at_rest=at_rest)

    def roll_released(self, vel: np.ndarray, released: np.ndarray, supported: np.ndarray) -> None:
        """In place on ``vel (K, M, 6)``: balls let go now (``released (K, M)``) on a support
        (``supported (K, M)``) or just after they were seen rolling along one (off an edge) roll at
        their velocity (:func:`~estimator.model.motion.roll_released`)."""
        rolled = released & (supported | rolled_along(self.memory.previous_tick_velocity())[None, :])
        if np.any(rolled):
            roll_released(vel, rolled, self.ball_radius)

    def batch(self, move: Move, state: ParticleState) -> BatchInput:
        """The pool's input for ``move`` (which entries to load, and which a world produced at rest,
        the pool's cache decides: :meth:`~estimator.worlds.pool.WorldPool.advance`)."""
        params = world_params(state.params, state.on_top, state.is_in)
        return BatchInput(poses=move.poses, velocities=move.velocities, params=params, modes=move.modes,
                          check=move.check, target=move.target, target_vel=move.target_vel, contents=state.is_in,
                          depenetrate=move.depenetrate, vis_query=move.vis_query)

    def _out_of_reach(self, frame: Frame, detected: np.ndarray) -> np.ndarray | None:
        """Dynamic objects ``(M,)`` detected since the last update whose latest detection lies farther
        than :data:`~estimator.model.hand_memory.HAND_RADIUS` from every hand tracked in ``frame``;
        None when no hand is tracked in it or hands are not followed."""
        if not self.config.follow_hands:
            return None
        return out_of_reach(self.memory.last_pose[:, :3], frame.hands, detected & self.dynamic, HAND_RADIUS)

    # -- after resampling -----------------------------------------------------------------------------

    # -- after physics --------------------------------------------------------------------------------
    def settle(self, state: ParticleState, move: Move, out: BatchOutput, t: float, dt: float,
               detected: np.ndarray, perceived: np.ndarray) -> Settled:
        """The particles after physics (``out``) and the Place / Release rules, with the update's events
        (:func:`~estimator.model.settle.settle`)."""
        return settling.settle(self, state, move, out, t, dt, detected, perceived)

    def evidence(self, move: Move, settled: Settled, out: BatchOutput, frame: Frame, detected: np.ndarray,
                 perceived: np.ndarray, unseen_in_view: np.ndarray) -> Evidence:
        """What the log-weight terms read for this update (:func:`~estimator.model.weighing.evidence`)."""
        return weighing.evidence(self, move, settled, out, frame, detected, perceived, unseen_in_view)

    def log_weight(self, previous: np.ndarray, ev: Evidence) -> np.ndarray:
        """New log-weights ``(K,)``: ``previous (K,)`` plus every term of :attr:`terms`
        (:func:`~estimator.model.weighing.log_weight`)."""
        return weighing.log_weight(self, previous, ev)
