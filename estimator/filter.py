"""The particle estimator: K perturbed Bullet worlds weighted into a belief.

``SceneEstimator(scene, config, rng).update(frame)`` runs one reasoning step when the stream's time has
advanced by the configured horizon, and returns a :class:`~estimator.belief.Belief` (``None`` for
frames that only update the perception memory). With one particle and :meth:`NoiseConfig.off` it *is*
the physics reasoner of Sallami et al. (IROS 2019), its "paper mode".

One update (time t, previous update at t0, ``n = round((t - t0) / time_step)`` simulation steps; the
first update simulates nothing, so that simulated time is the stream's time):

1. perception memory: last perceived pose, time and velocity (finite differences) of each object;
   perceived = seen within ``t_perceived``;
2. teleports (Alg. 2): an object perceived again after being unperceived, or whose perception jumped by
   more than ``d_perc_prev``, is placed at its perceived pose (plus perception noise per particle), and
   its contents are carried along, rotation included;
3. modes: a held object that stops being perceived is released in a ``release_on_loss`` fraction of
   the particles (the rest keep holding it: it follows the nearest tracked hand, or stays put with
   growing noise); held, unperceived objects are released later with hazard ``release``;
4. process noise on unperceived free objects;
5. physics (Alg. 1, in every particle's own world): held objects follow their targets; free perceived
   objects that diverge by more than ``d_sim_perc`` are picked (switch to held);
6. a held object perceived at rest on a support is put down (Place);
7. weights: heavy-tailed likelihood of the detections, negative evidence for undetected objects in
   view of the camera, log-prior of the Pick / Place switches; exploded particles get zero weight;
8. belief and timeline; resampling when the effective sample size is below the threshold, with
   shrinkage jitter of the physical parameters.
"""
from __future__ import annotations

import logging
import math
from collections import deque

import numpy as np

from actions.events import recent_events, record_event_times
from actions.modes import FREE, HELD, merge_events, switch_events
from physics.scene import Scene
from physics.transforms import carry_pose, quat_angle, quat_from_rotvec, quat_multiply

from .belief import Belief, compute_belief, pose_stats
from .config import EstimatorConfig
from .observations import Frame
from .pool import BatchInput, WorldPool
from .relations import relations_and_support
from .resampling import effective_sample_size, normalise_log_weights, systematic_resample
from .timeline import Timeline

log = logging.getLogger(__name__)

LOG_2PI = math.log(2.0 * math.pi)


class SceneEstimator:
    """Particle filter over pybullet worlds for one scene.

    Args:
        scene: the scene (static objects, shapes, initial poses, optional camera).
        config: estimator configuration; :meth:`EstimatorConfig.paper` for the paper's reasoner.
        rng: source of all randomness (default: ``numpy.random.default_rng(0)``).

    Particle state (structure of arrays; K particles, M objects): ``poses (K, M, 7)``,
    ``velocities (K, M, 6)``, ``params (K, M, 5)`` (lateral / rolling / spinning friction,
    restitution, mass in kg), ``modes (K, M)`` int8 (FREE / HELD), ``log_weights (K,)``,
    ``on_top (K, M, M+1)`` and ``is_in (K, M, M)`` (relations at the last update).
    """

    def __init__(self, scene: Scene, config: EstimatorConfig | None = None,
                 rng: np.random.Generator | None = None):
        self.scene = scene
        self.config = cfg = config or EstimatorConfig.paper()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.object_ids = scene.object_ids
        K, M = cfg.particles, len(scene.objects)
        self.K, self.M = K, M
        self.static = np.array([o.static for o in scene.objects], dtype=bool)
        self.hollow = np.array(scene.hollow, dtype=bool)
        self.dynamic = ~self.static
        self.pool = WorldPool(scene, K, cfg.workers, cfg.physics, cfg.worlds)
        try:
            self._init_state()
        except BaseException:
            self.pool.close()
            raise
        self.timeline = Timeline(cfg.event_threshold)
        self.recoveries = 0
        self.n_updates = 0
        self.last_belief: Belief | None = None

    # -- set-up ---------------------------------------------------------------------------------------
    def _init_state(self) -> None:
        K, M, cfg = self.K, self.M, self.config
        rng = self.rng
        poses = np.zeros((M, 7))
        poses[:, 6] = 1.0
        self.known = np.zeros(M, dtype=bool)
        for i, o in enumerate(self.scene.objects):
            if o.position is not None:
                poses[i, :3] = o.position
                poses[i, 3:] = o.orientation
                self.known[i] = True
            else:
                poses[i, :3] = [50.0 + 3.0 * i, 50.0, -50.0]  # parked until first perceived
        self.poses = np.repeat(poses[None], K, axis=0)
        self.velocities = np.zeros((K, M, 6))
        self.modes = np.zeros((K, M), dtype=np.int8)
        self.log_weights = np.zeros(K)
        base = self.pool.initial_params
        self.params = np.repeat(base[None], K, axis=0)
        nz = cfg.noise
        dyn = np.flatnonzero(self.dynamic)
        ranges = [nz.friction_range, nz.rolling_friction_range, nz.spinning_friction_range,
                  nz.restitution_range]
        for col, r in enumerate(ranges):
            if r is not None:
                self.params[:, dyn, col] = rng.uniform(r[0], r[1], size=(K, len(dyn)))
        if nz.mass_scale_range is not None:
            lo, hi = nz.mass_scale_range
            self.params[:, dyn, 4] = base[dyn, 4] * rng.uniform(lo, hi, size=(K, len(dyn)))
        self._param_bounds = self._bounds(base)
        self._just_initialised = np.zeros(M, dtype=bool)
        if nz.position_std > 0:
            known_dyn = np.flatnonzero(self.dynamic & self.known)
            self.poses[:, known_dyn, :3] += rng.normal(0, nz.position_std, (K, len(known_dyn), 3))
            self._just_initialised[known_dyn] = True
        self.event_t = np.full((K, M, 3), -np.inf)
        self.on_top = np.zeros((K, M, M + 1), dtype=bool)
        self.is_in = np.zeros((K, M, M), dtype=bool)
        # perception memory (shared by all particles)
        self.last_pose = poses.copy()
        self.last_has_orientation = np.zeros(M, dtype=bool)
        self.last_seen = np.full(M, -np.inf)
        self.last_std = np.full(M, np.nan)
        self.perc_vel = np.zeros((M, 6))
        self.pose_at_tick = poses.copy()
        self.perceived_prev = np.zeros(M, dtype=bool)
        self.hold_hand: list[str | None] = [None] * M
        self.hold_offset = np.zeros((M, 3))
        self.t_frame: float | None = None
        self.t_tick: float | None = None
        self._detected_since_tick = np.zeros(M, dtype=bool)
        self._world_poses: np.ndarray | None = None
        self._supported = np.zeros((K, M), dtype=bool)
        self._last_motion = np.zeros((K, M))
        self._jolted = np.zeros((K, M), dtype=bool)
        self._prev_tick_vel = np.zeros((M, 3))
        self._t_seen_at_tick = np.full(M, -np.inf)
        self._history: list[deque] = [deque() for _ in range(M)]
        self._world_vel: np.ndarray | None = None

    def _bounds(self, base: np.ndarray) -> np.ndarray:
        nz = self.config.noise
        b = np.zeros((5, 2))
        for col, r in enumerate([nz.friction_range, nz.rolling_friction_range,
                                 nz.spinning_friction_range, nz.restitution_range]):
            b[col] = r if r is not None else (0.0, np.inf)
        b[4] = (1e-4, np.inf)
        return b

    # -- life cycle -----------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the particle worlds (and worker processes)."""
        self.pool.close()

    def __enter__(self) -> "SceneEstimator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the update -----------------------------------------------------------------------------------
    def _record(self, frame: Frame) -> np.ndarray:
        """Store the frame's detections in the perception memory; returns the detected mask (M,)."""
        detected = np.zeros(self.M, dtype=bool)
        for oid, det in frame.objects.items():
            try:
                m = self.scene.index(oid)
            except KeyError:
                raise ValueError(f"frame at t={frame.t}: unknown object id {oid!r}") from None
            if self.static[m]:
                continue
            detected[m] = True
            gap = frame.t - self.last_seen[m]
            if 0 < gap <= self.config.reasoner.t_perceived:
                self.perc_vel[m, :3] = (det.position - self.last_pose[m, :3]) / gap
            else:
                self.perc_vel[m, :3] = 0.0  # first sighting: no velocity (never NaN)
            self.last_pose[m, :3] = det.position
            if det.orientation is not None:
                self.last_pose[m, 3:] = det.orientation
            self.last_has_orientation[m] = det.orientation is not None
            self.last_std[m] = det.position_std if det.position_std is not None else np.nan
            self.last_seen[m] = frame.t
            hist = self._history[m]
            hist.append((frame.t, tuple(det.position.tolist()),
                         None if det.orientation is None else tuple(det.orientation.tolist())))
            while hist and hist[0][0] < frame.t - 2.0 * self.config.reasoner.place_dwell - 0.1:
                hist.popleft()
            self._nearest_hand(frame, m)
        return detected

    def _nearest_hand(self, frame: Frame, m: int) -> None:
        """Remember the tracked hand nearest to object m (within 0.3 m) and the offset to it."""
        self.hold_hand[m] = None
        if not frame.hands:
            return
        names = list(frame.hands)
        hp = np.array([frame.hands[n] for n in names])
        d = np.linalg.norm(hp - self.last_pose[m, :3], axis=1)
        best = int(np.argmin(d))
        if d[best] < 0.3:
            self.hold_hand[m] = names[best]
            self.hold_offset[m] = self.last_pose[m, :3] - hp[best]

    def update(self, frame: Frame) -> Belief | None:
        """Process one perception frame; returns the belief if a reasoning step ran, else None."""
        if self.t_frame is not None and not frame.t > self.t_frame:
            raise ValueError(f"frame time must increase: {frame.t} after {self.t_frame}")
        detected = self._record(frame)
        self.t_frame = frame.t
        self._detected_since_tick |= detected
        hr = self.config.reasoner
        if self.t_tick is not None and frame.t < self.t_tick + hr.horizon - 1e-9:
            return None
        detected = self._detected_since_tick
        self._detected_since_tick = np.zeros(self.M, bool)
        belief = self._tick(frame, detected)
        self.last_belief = belief
        return belief

    def _tick(self, frame: Frame, detected: np.ndarray) -> Belief:
        cfg, nz, hr = self.config, self.config.noise, self.config.reasoner
        rng = self.rng
        K, M = self.K, self.M
        t = frame.t
        # the first update only places the objects: simulated time follows the stream's time
        dt = 0.0 if self.t_tick is None else t - self.t_tick
        step = cfg.physics.time_step
        n_steps = int(round(dt / step))
        perceived = self.dynamic & (t - self.last_seen <= hr.t_perceived + 1e-9)
        poses = self.poses.copy()
        vel = self.velocities.copy()
        modes = self.modes.copy()
        prev_modes = modes.copy()
        predicted = poses.copy()  # before teleports: what each particle expected

        # 2. teleports and first sightings
        newly_known = perceived & ~self.known
        jump = np.linalg.norm(self.last_pose[:, :3] - self.pose_at_tick[:, :3], axis=1) > hr.d_perc_prev
        tele = perceived & (~self.perceived_prev | jump | newly_known)
        self.perc_vel[tele] = 0.0  # a finite difference across a jump or a gap is no velocity
        if np.any(tele):
            self._teleport(poses, vel, np.flatnonzero(tele), newly_known)
        self.known |= perceived

        # 3. releases of held objects that are not perceived
        lost = self.perceived_prev & ~perceived
        u = rng.random((K, M))
        held_unseen = (modes == HELD) & ~perceived[None, :]
        p_rel = np.where(lost[None, :], cfg.priors.release_on_loss, cfg.priors.release)
        released = held_unseen & (u < p_rel)
        modes[released] = FREE
        codes_release = switch_events(prev_modes, modes, self._supported)
        modes_before_physics = modes.copy()

        # targets of held objects
        target = poses.copy()
        target_vel = np.zeros((K, M, 6))
        pidx = np.flatnonzero(perceived)
        if len(pidx):
            # a held object follows the perception itself: noise here would shake what it carries
            target[:, pidx, :3] = self.last_pose[pidx, :3]
            has_q = self.last_has_orientation[pidx]
            target[:, pidx[has_q], 3:] = self.last_pose[pidx[has_q], 3:]
            target_vel[:, pidx, :3] = self.perc_vel[pidx, :3]
        held_undetected = (modes == HELD) & ~detected[None, :]
        if np.any(held_undetected):
            self._held_targets(frame, target, held_undetected, perceived, dt)

        # 4. process noise on unperceived free objects
        # (a random walk, plus model error in proportion to how far the object moved on or in its
        # support in the last update: rolling and sliding are chaotic)
        free_unseen = (modes == FREE) & (~perceived & self.dynamic & self.known)[None, :]
        jolted = np.zeros((K, M), dtype=bool)
        if (nz.process_position_std > 0 or nz.motion_noise > 0) and np.any(free_unseen):
            rolling = np.where(self._supported, self._last_motion, 0.0)  # flight is predictable
            s = np.sqrt(nz.process_position_std ** 2 * dt + (nz.motion_noise * rolling) ** 2)
            s = np.minimum(s, nz.max_jitter_std)  # never through a wall
            poses[..., :3] += np.where(free_unseen[..., None], rng.normal(0.0, 1.0, (K, M, 3)) * s[..., None], 0.0)
            jolted = free_unseen & (s > 0.002)
        if nz.process_orientation_std > 0 and np.any(free_unseen):
            s = nz.process_orientation_std * math.sqrt(dt)
            dq = quat_from_rotvec(rng.normal(0.0, s, (K, M, 3)))
            rotated = quat_multiply(dq, poses[..., 3:])
            poses[..., 3:] = np.where(free_unseen[..., None], rotated, poses[..., 3:])

        # 5. physics in every particle's world
        vis_query = self.known & self.dynamic & ~detected
        if not (cfg.negative_evidence and self.scene.camera is not None):
            vis_query = np.zeros(M, dtype=bool)
        fresh = detected if cfg.fresh_checks else perceived
        check = np.broadcast_to(perceived & fresh, (K, M)).copy()
        placed = tele | self._just_initialised
        self._just_initialised = np.zeros(M, dtype=bool)
        depen = (np.broadcast_to(placed & (nz.position_std > 0), (K, M)) | jolted | self._jolted) & (modes == FREE)
        self._jolted = np.zeros((K, M), dtype=bool)
        # only entries changed since the worlds last wrote them need loading back (a slot's world
        # always holds the state it produced, so this does not depend on the number of workers)
        if self._world_poses is None:
            reset = np.ones((K, M), dtype=bool)
        else:
            reset = (np.any(poses != self._world_poses, axis=-1) | np.any(vel != self._world_vel, axis=-1))
        batch = BatchInput(poses, vel, self.params, modes, check, target, target_vel, self.is_in, depen,
                           reset, vis_query)
        out = self.pool.run(batch, n_steps, hr.d_sim_perc, cfg.lazy_checks)
        new_poses, new_vel, new_modes = out.poses, out.velocities, out.modes
        aabbs = out.aabbs
        bad = ~out.finite
        if np.any(bad):
            log.warning("t=%.3f: %d particle simulation(s) exploded; their state is reset", t, bad.sum())
            new_poses[bad] = poses[bad]
            new_vel[bad] = 0.0
            new_modes[bad] = modes[bad]

        # 6. relations; Place: a held object perceived at rest on a support is put down; Release in
        # view: a held object perceived falling, with nothing under it, was let go
        valid = np.broadcast_to(self.known, (K, M))
        on_top, is_in, supported = relations_and_support(
            aabbs, valid, static=self.static, floor=self.scene.floor, config=cfg.relations,
            previous=(self.on_top, self.is_in), z_gap=hr.place_gap, hollow=self.hollow)
        rested = self._at_rest(t)
        vel = self._tick_velocity(t)
        accel = (vel[:, 2] - self._prev_tick_vel[:, 2]) / max(dt, 1e-9)
        # fast enough, it is let go whatever is under it; accelerating down, only if nothing is
        falling = (vel[:, 2] < -hr.release_speed)[None, :] | (
            ((accel < -hr.release_accel) & (vel[:, 2] < -0.3))[None, :] & ~supported)
        self._prev_tick_vel = np.where(detected[:, None], vel, 0.0)
        held_seen = (new_modes == HELD) & perceived[None, :]
        after_physics = new_modes.copy()
        new_modes[held_seen & ((rested[None, :] & supported) | falling)] = FREE

        # 7. weights
        codes = merge_events(codes_release,
                             switch_events(modes_before_physics, after_physics, supported),
                             switch_events(after_physics, new_modes, supported))
        logw = self.log_weights.copy()
        if K > 1:
            logw += self._log_likelihood(new_poses, predicted, detected, tele)
            if np.any(vis_query):
                # an object in a tracked hand may be hidden by the hand or the person, whom the
                # particle worlds do not contain: no negative evidence for it
                in_hand = (new_modes == HELD) & self._following_hand(frame)[None, :]
                seen = (out.visible >= cfg.visibility_threshold) & ~in_hand
                logw += math.log(nz.miss_prob) * seen[:, vis_query].sum(axis=1)
            logw += cfg.priors.log_prior_cost(prev_modes, new_modes, perceived[None, :]).sum(axis=1)
        logw[bad] = -np.inf
        weights, _ = normalise_log_weights(logw)
        if not np.any(np.isfinite(logw)):
            self._recover(t, new_poses, new_vel, detected)
            logw = np.zeros(K)
            weights = np.full(K, 1.0 / K)
        ess = effective_sample_size(weights)

        # commit the state
        self._last_motion = np.linalg.norm(new_poses[..., :3] - poses[..., :3], axis=-1)
        self._supported = supported
        self._world_poses, self._world_vel = new_poses.copy(), new_vel.copy()
        if np.any(bad):  # exploded worlds must be reloaded from the arrays
            self._world_poses[bad] = np.nan
        self.poses, self.velocities, self.modes = new_poses, new_vel, new_modes
        self.on_top, self.is_in = on_top, is_in
        self.log_weights = logw - np.max(logw[np.isfinite(logw)])
        self.perceived_prev = perceived
        self.pose_at_tick = self.last_pose.copy()
        self._t_seen_at_tick = self.last_seen.copy()
        self.t_tick = t
        self.n_updates += 1

        # 8. belief and timeline
        record_event_times(self.event_t, codes, t)
        step_events = recent_events(self.event_t, weights, t, cfg.event_window, self.object_ids,
                                    threshold=cfg.hypothesis_min_p)
        belief = compute_belief(t, self.object_ids, self.known, perceived, new_poses, weights, new_modes,
                                on_top, is_in, step_events, ess, self.static, cfg.hypothesis_min_p,
                                cov_floor=nz.covariance_floor_std ** 2)
        self._update_timeline(t, belief)
        if K > 1 and ess < cfg.resample_threshold * K:
            self._resample(weights, self.known & self.dynamic & ~perceived)
        return belief

    # -- pieces of the update -------------------------------------------------------------------------
    def _tick_velocity(self, t: float) -> np.ndarray:
        """Perceived velocity ``(M, 3)`` (m/s) over the last reasoning period (smoother than
        frame-to-frame differences): from the detections used at the previous update to the latest."""
        ok = np.isfinite(self.last_seen) & np.isfinite(self._t_seen_at_tick)
        gap = np.where(ok, self.last_seen - np.where(ok, self._t_seen_at_tick, 0.0), 0.0)
        ok &= gap > 1e-6
        vel = np.zeros((self.M, 3))
        vel[ok] = (self.last_pose[ok, :3] - self.pose_at_tick[ok, :3]) / gap[ok, None]
        return vel

    def _at_rest(self, t: float) -> np.ndarray:
        """Objects ``(M,)`` whose detections over the last ``place_dwell`` seconds moved less than
        ``place_speed * place_dwell`` and turned less than ``place_spin * place_dwell``."""
        hr = self.config.reasoner
        out = np.zeros(self.M, dtype=bool)
        horizon = t - hr.place_dwell + 1e-9
        for m, hist in enumerate(self._history):
            if not hist or t - hist[-1][0] > hr.place_dwell:
                continue
            old = next((h for h in reversed(hist) if h[0] <= horizon), None)  # the latest one old enough
            if old is None:
                continue
            t0, p0, q0 = old
            t1, p1, q1 = hist[-1]
            span = max(t1 - t0, hr.place_dwell)
            moved = math.dist(p0, p1) < hr.place_speed * span
            turned = True
            if q0 is not None and q1 is not None:
                dot = min(1.0, abs(sum(a * b for a, b in zip(q0, q1))))
                turned = 2.0 * math.acos(dot) < hr.place_spin * span
            out[m] = moved and turned
        return out

    def _following_hand(self, frame: Frame) -> np.ndarray:
        """Objects ``(M,)`` whose hand (when last detected) is tracked in this frame."""
        if not self.config.follow_hands:
            return np.zeros(self.M, dtype=bool)
        return np.array([h is not None and h in frame.hands for h in self.hold_hand])

    def _teleport(self, poses: np.ndarray, vel: np.ndarray, idx: np.ndarray, newly_known: np.ndarray) -> None:
        nz = self.config.noise
        K = self.K
        new = poses[:, idx].copy()
        new[..., :3] = self.last_pose[idx, :3]
        if nz.position_std > 0:
            new[..., :3] += self.rng.normal(0.0, nz.position_std, new[..., :3].shape)
        has_q = self.last_has_orientation[idx]
        new[:, has_q, 3:] = self.last_pose[idx[has_q], 3:]
        if nz.orientation_std > 0 and np.any(has_q):
            dq = quat_from_rotvec(self.rng.normal(0.0, nz.orientation_std / 4, (K, int(has_q.sum()), 3)))
            new[:, has_q, 3:] = quat_multiply(dq, new[:, has_q, 3:])
        # contents (isIn at the last update, per particle) move with their container
        moved = set(int(i) for i in idx)
        for j, b in enumerate(idx):
            if newly_known[b]:
                continue
            for k in range(K):
                children = [a for a in np.flatnonzero(self.is_in[k, :, b]) if a not in moved]
                if children:
                    poses[k, children] = carry_pose(poses[k, children], poses[k, b], new[k, j])
                    vel[k, children, :3] = self.perc_vel[b, :3]
        poses[:, idx] = new
        vel[:, idx] = 0.0
        vel[:, idx, :3] = self.perc_vel[idx, :3]

    def _held_targets(self, frame: Frame, target: np.ndarray, held: np.ndarray, perceived: np.ndarray,
                      dt: float) -> None:
        """Targets of held objects not detected in this update: the hand that held them when last
        detected, if it is tracked; else where they were last perceived (while perceived) or where
        the particle has them, with a drift that grows the uncertainty."""
        nz = self.config.noise
        for m in np.flatnonzero(held.any(axis=0)):
            rows = held[:, m]
            hand = self.hold_hand[m]
            if hand is not None and hand in frame.hands and self.config.follow_hands:
                target[rows, m, :3] = np.asarray(frame.hands[hand]) + self.hold_offset[m]
            elif not perceived[m] and nz.held_drift_std > 0:
                target[rows, m, :3] += self.rng.normal(0.0, nz.held_drift_std * math.sqrt(dt),
                                                       (int(rows.sum()), 3))

    def _log_likelihood(self, poses: np.ndarray, predicted: np.ndarray, detected: np.ndarray,
                        tele: np.ndarray) -> np.ndarray:
        """Heavy-tailed log-likelihood ``(K,)`` of the detections of this update."""
        nz = self.config.noise
        idx = np.flatnonzero(detected & self.dynamic)
        if len(idx) == 0:
            return np.zeros(self.K)
        src = np.where(tele[idx][None, :, None], predicted[:, idx], poses[:, idx])
        std = np.where(np.isfinite(self.last_std[idx]), self.last_std[idx], max(nz.position_std, 1e-3))
        e2 = np.sum((src[..., :3] - self.last_pose[idx, :3]) ** 2, axis=-1)
        log_n = -0.5 * e2 / std**2 - 1.5 * np.log(2 * math.pi * std**2)
        eps = nz.outlier_prob
        if eps > 0:
            ll = np.logaddexp(math.log1p(-eps) + log_n, math.log(eps))  # outliers: uniform over 1 m^3
        else:
            ll = log_n
        has_q = self.last_has_orientation[idx]
        if nz.orientation_std > 0 and np.any(has_q):
            q_idx = idx[has_q]
            ang = quat_angle(src[:, has_q, 3:], self.last_pose[q_idx, 3:])
            lo = -0.5 * (ang / nz.orientation_std) ** 2
            if eps > 0:
                lo = np.logaddexp(math.log1p(-eps) + lo, math.log(eps))
            ll[:, has_q] += lo
        return ll.sum(axis=1)

    def _recover(self, t: float, poses: np.ndarray, vel: np.ndarray, detected: np.ndarray) -> None:
        self.recoveries += 1
        log.warning("t=%.3f: every particle has zero weight; re-seeding detected objects from perception", t)
        idx = np.flatnonzero(detected & self.dynamic)
        if len(idx):
            poses[:, idx, :3] = self.last_pose[idx, :3]
            if self.config.noise.position_std > 0:
                poses[:, idx, :3] += self.rng.normal(0.0, self.config.noise.position_std,
                                                     (self.K, len(idx), 3))
            vel[:, idx] = 0.0

    def _resample(self, weights: np.ndarray, hidden: np.ndarray) -> None:
        """Systematic resampling; then the positions of hidden free objects (``hidden (M,)``) are
        jittered with a Gaussian kernel of bandwidth ``h`` times their weighted covariance (a
        regularised particle filter: copies of one particle must not leave a hidden object with no
        spread), and the physical parameters with Liu-West shrinkage."""
        anc = systematic_resample(weights, self.rng)
        K = self.K
        h = self.config.noise.regularisation
        kernels = {}
        if h > 0:
            _, covs, _, _ = pose_stats(self.poses, weights)
            for m in np.flatnonzero(hidden):
                cov = covs[m]
                if np.trace(cov) > 1e-10:
                    chol = np.linalg.cholesky(cov * h * h + 1e-12 * np.eye(3))
                    largest = np.sqrt(np.max(np.linalg.eigvalsh(cov)) * h * h)
                    kernels[m] = chol * min(1.0, self.config.noise.max_jitter_std / largest)
        # per-particle state follows its ancestor; _world_poses stays: it is what each slot's world holds
        for name in ("poses", "velocities", "params", "modes", "on_top", "is_in", "event_t", "_supported",
                     "_last_motion"):
            setattr(self, name, getattr(self, name)[anc].copy())
        self.log_weights = np.zeros(self.K)
        for m, chol in kernels.items():
            free = self.modes[:, m] == FREE
            noise = self.rng.standard_normal((K, 3)) @ chol.T
            self.poses[free, m, :3] += noise[free]
            self._jolted[free, m] = True
        self._jitter_params(weights[anc] / weights[anc].sum())

    def _jitter_params(self, w: np.ndarray) -> None:
        """Liu-West shrinkage: keep each parameter's mean and spread while avoiding collapse."""
        h = self.config.noise.param_jitter
        if h <= 0:
            return
        a = math.sqrt(1.0 - h * h)
        dyn = np.flatnonzero(self.dynamic)
        p = self.params[:, dyn]
        mean = np.mean(p, axis=0)
        std = np.std(p, axis=0)
        p = a * p + (1 - a) * mean + h * std * self.rng.standard_normal(p.shape)
        lo, hi = self._param_bounds[:, 0], self._param_bounds[:, 1]
        self.params[:, dyn] = np.clip(p, lo, hi)

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
