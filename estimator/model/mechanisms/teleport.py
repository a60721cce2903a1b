"""Teleports (Alg. 2 of the paper): an object perceived after a gap, a jump or for the first time is
put where it is perceived, with what is in it.

With ``moving_teleports`` (the full model) an object tracked in motion keeps moving: teleported, it
starts where it was at the update's start with the velocity fitted to its detections; one seen
rolling off an edge is put on the free fall through its detections; and one at rest in its particle,
seen to start moving with no tracked hand within reach, was set moving by an agent nobody tracks (a
Push, not a Pick): physics takes it on at its velocity. In the paper's mode it is placed at its
detection, at rest.
"""
from __future__ import annotations

import numpy as np

from actions.modes import is_free, is_held

from ..motion import MOVING_MAX_VERTICAL_SPEED, place, teleport_kinds
from ..step import Fall
from .base import Draft, Mechanism

SET_MOVING_SIGMAS = 4.0
"""An object at rest is set moving by an agent nobody tracks only when its perceived horizontal
speed exceeds this many standard errors of the fitted velocity (per axis). The speed pure detection
noise gives a still object is Rayleigh: it exceeds k errors with probability exp(-k^2 / 2), and a
run checks every still object at every update (ten objects over 50 updates: 500 checks), so k = 3
(1 %) would set a few still objects moving per run; k = 4 (3e-4), one run in seven."""


def moving_beyond_noise(memory, position_std: float) -> np.ndarray:
    """``(M,)`` bool: objects whose perceived horizontal speed (``memory``:
    :class:`~estimator.model.perception_memory.PerceptionMemory`) exceeds :data:`SET_MOVING_SIGMAS`
    standard errors of their fitted velocity (per axis): seen moving, not merely noisy."""
    speed = np.linalg.norm(memory.perc_vel[:, :2], axis=1)
    return speed > SET_MOVING_SIGMAS * memory.velocity_std(position_std)


class Teleports(Mechanism):
    """Alg. 2, and with ``moving`` its moving variant (see the module docstring)."""

    def __init__(self, model, moving: bool = True):
        super().__init__(model)
        self.moving = moving

    def perceive(self, u: Draft) -> None:
        model, mem, cfg = self.model, self.model.memory, self.model.config
        state, perceived, detected, dt = u.state, u.perceived, u.detected, u.dt
        if self.moving:  # what each particle expected at frame.t: carried on at its velocity, without
            # the last teleport's noise (the paper: where it was)
            u.predicted[..., :3] += u.vel[..., :3] * dt - state.jitter
            # moving along, or rolled off an edge: keeps its velocity and spin
            moving, falling = teleport_kinds(perceived & mem.perceived_prev & ~u.newly_known & detected, u.tick_vel,
                                             mem.previous_tick_velocity())
            if cfg.noise_aware_jumps:  # falling off an edge: seen moving (a motion onset beyond the tracker's
                falling &= np.isfinite(mem.moving_since)  # noise), not a still object's noisy detections
            # seen rolling off an edge (with no tracked hand to move it), it is placed on its fall
            # even if it moved little since the last update (one late detection): a fixed target
            # would make it held in the air
            u.tele = u.tele | (falling & ~u.following)
            u.moving, u.falling = moving & u.tele, falling & u.tele
        tele, falling = u.tele, u.falling
        spinning = u.moving | falling
        # teleported in motion, an object keeps the detections' fitted velocity (falling, its
        # horizontal part, and the vertical one of a free fall, below); at rest, none
        mem.teleported(tele & ~spinning, falling)
        # an object teleported in motion starts where it was at this update's start, so that physics
        # brings it to its detection at frame.t (placed at the detection, the belief would be dt ahead)
        u.start = start = mem.position_at(u.t - dt) if self.moving else None
        fall = np.zeros(model.M, dtype=bool)
        if self.moving and np.any(falling):  # ... falling, on the free fall through its last detections
            (z0, z1), (vz0, _), vz_std = mem.free_fall((u.t - dt, u.t), cfg.physics.gravity, cfg.noise.position_std)
            fall = falling & np.isfinite(z0) & ~u.following
            start[fall, 2] = z0[fall]
            mem.set_vertical_velocity(fall, vz0)
            u.fall = Fall(fall, z1, (z1 - z0) / dt)
        if np.any(tele):
            u.jitter[:, tele] = self.teleport(u.poses, u.vel, np.flatnonzero(tele), u.newly_known, state.is_in,
                                              u.rng, spinning, start, is_held(u.prev_modes), u.level)
            u.jitter[..., 2] = 0.0  # a support undoes the vertical noise: only the horizontal persists
            if np.any(fall):  # when the fall began is known to the vertical velocity's error
                u.vel[:, fall, 2] += u.rng.normal(0.0, 1.0, (model.K, int(fall.sum()))) * vz_std[fall]
            if self.moving:
                self._set_moving(u)
        model.known |= perceived

    def _set_moving(self, u: Draft) -> None:
        """At rest in a particle, nothing in its world set it moving: an agent did; it stays, and
        diverges from its target, held, if one can reach it (a Pick needs an agent within reach, a
        tracked hand); with none, it was set moving (flicked, knocked) and physics takes it on at its
        velocity (:attr:`Draft.set_moving`)."""
        model, mem, cfg, state = self.model, self.model.memory, self.model.config, u.state
        started = ((u.moving | u.falling)[None, :] & is_free(u.prev_modes) & (np.linalg.norm(
            state.velocities[..., :2], axis=-1) < MOVING_MAX_VERTICAL_SPEED))
        unreached = np.ones(model.M, dtype=bool) if u.far is None else u.far
        # seen moving beyond what the detection noise makes of a still object (a horizontal speed past
        # SET_MOVING_SIGMAS standard errors of the fitted velocity): noise is no agent
        set_moving = started & (u.moving & unreached & moving_beyond_noise(mem, cfg.noise.position_std))[None, :]
        fresh = np.isfinite(mem.moving_since) & (mem.moving_since >= u.t - u.dt - cfg.reasoner.place_dwell)
        set_moving &= fresh[None, :] & (np.linalg.norm(state.velocities[..., :3], axis=-1)
                                        < model.episode_rule.rest_speed)
        u.vel[started & ~set_moving] = 0.0
        u.set_moving = set_moving

    def teleport(self, poses: np.ndarray, vel: np.ndarray, idx: np.ndarray, newly_known: np.ndarray,
                 is_in: np.ndarray, rng: np.random.Generator, spinning: np.ndarray | None = None,
                 start: np.ndarray | None = None, held: np.ndarray | None = None,
                 level: np.ndarray | None = None) -> np.ndarray:
        """Alg. 2 (:func:`~estimator.model.motion.place`), in place on ``poses (K, M, 7)`` and ``vel (K, M,
        6)``: objects ``idx`` at their last detection, or at ``start (M, 3)`` m (the detections
        carried back to the update's start,
        :meth:`~estimator.model.perception_memory.PerceptionMemory.position_at`), with the memory's perceived
        velocities (and, teleported in motion, their standard error as velocity noise); those of
        ``level (M,)`` keep each particle's height and orientation. Returns the position noise
        ``(K, len(idx), 3)`` m."""
        mem, nz = self.model.memory, self.model.config.noise
        positions = mem.last_pose[:, :3] if start is None else start
        return place(poses, vel, idx, newly_known, is_in, positions, mem.last_pose[:, 3:], mem.last_has_orientation,
                     mem.perc_vel, nz, rng, spinning, held, self.model.ball_radius, mem.velocity_std(nz.position_std),
                     held if self.moving else None, level)
