"""After physics: the particles' relations, the Place / Release rules and the update's events.

Functions of the scene model (:class:`~estimator.model.SceneModel`, passed as ``model``): K particles,
M objects; positions in metres, times in seconds. :func:`settle` is what
:meth:`~estimator.model.SceneModel.settle` runs.
"""
from __future__ import annotations

import numpy as np

from actions.episodes import Switches, carried, update_events
from actions.modes import FREE, HELD, PUSH, is_free, is_held
from actions.push import REF_Z, late_picks

from ..config_sections import RELEASE_DOWN_SPEED
from ..relations import relations_and_support, supported_mask
from ..state import ParticleState
from ..worlds.pool import BatchOutput
from .hidden import dropped_behind_cover
from .mechanisms.teleport import moving_beyond_noise
from .motion import rolled_along
from .step import Move, Settled

CARRIER_SHIFT = 0.02
"""An object perceived moving and more than this (m) away horizontally from where it was still
(:meth:`~estimator.model.perception_memory.PerceptionMemory.shifted`) carries what is in or on it: those
get no events of their own (:meth:`SceneModel.settle`)."""


def settle(model, state: ParticleState, move: Move, out: BatchOutput, t: float, dt: float,
           detected: np.ndarray, perceived: np.ndarray) -> Settled:
    """Relations of the particles ``out`` gives (their exploded ones already reset); Place: a held
    object perceived at rest on a support is let go; Release in view: a held object perceived
    falling (fast, or accelerating down with nothing under it) was let go; the events."""
    hr, cfg, mem = model.config.reasoner, model.config, model.memory
    for mechanism in model.mechanisms:
        out.poses = mechanism.after_physics(out.poses, out.aabbs)
    new_modes = out.modes.copy()  # out.modes stays what physics made (Evidence.diverged)
    valid = np.broadcast_to(model.known, (model.K, model.M))
    on_top, is_in, supported = relations_and_support(
        out.aabbs, valid, static=model.static, floor=model.scene.floor, config=cfg.relations,
        previous=(state.on_top, state.is_in), z_gap=hr.place_gap, hollow=model.hollow)
    rested = mem.at_rest(t)
    vel = mem.tick_velocity()
    accel = mem.vertical_acceleration(vel, dt)
    # fast enough, it is let go whatever is under it; accelerating down, only if nothing is
    falling = (vel[:, 2] < -hr.release_speed)[None, :] | (
        ((accel < -hr.release_accel) & (vel[:, 2] < -RELEASE_DOWN_SPEED))[None, :] & ~supported)
    held_seen = is_held(new_modes) & perceived[None, :]
    after_physics = out.modes
    put_down = held_seen & rested[None, :] & supported
    if np.any(put_down) and model.episode_rule.lift < hr.place_gap:
        # held still more than `lift` above its support (a box paused 2 cm up): let go, it would
        # drop that far and be held again by the episode rule (update_events); it is held
        put_down &= supported_mask(out.aabbs, is_in, valid, static=model.static, floor=model.scene.floor,
                                   z_gap=model.episode_rule.lift, config=cfg.relations)
    new_modes[put_down | (held_seen & falling)] = FREE
    # physics could not follow an object seen moving along its support, but no tracked hand can
    # reach it: no agent holds it; it goes on free at its perceived velocity (overridden in motion)
    unheld = unheld_overrides(model, move, out, supported, detected & perceived, vel)
    if unheld is not None:
        new_modes[unheld] = FREE
        after_physics = np.where(unheld, FREE, after_physics).astype(after_physics.dtype)
    # the switches read as actions (actions.episodes): a Pick dated when the object started
    # moving, a Place once physics confirms it (dated when it came to rest), a Push if unlifted
    rule, onset = model.episode_rule, mem.moving_since
    # what is in or on an object held, or perceived moving along its support (a pushed box not
    # yet held in this particle), is carried: whoever moves it moves its support
    carrier = np.where((mem.shifted(CARRIER_SHIFT) & perceived)[None, :], HELD, after_physics)
    silent = carried(state.is_in, state.on_top, carrier)
    if move.out_of_reach is not None:  # hands are tracked, none within reach of it: an action needs
        silent = silent | move.out_of_reach[None, :]  # an agent; its particle's physics moved it
    acted = np.isfinite(state.event_t).any(axis=-1)  # an event before this update
    if cfg.one_action_per_motion:  # a Push of this particle since the object was seen to start moving,
        # its latest event, explains that motion: held again while still seen moving, the push goes on
        pushed_t = state.event_t[..., PUSH - 1]
        with np.errstate(invalid="ignore"):
            silent = silent | ((pushed_t >= onset[None, :] - 1e-6) & (pushed_t >= np.max(state.event_t, axis=-1)))
    quiet = silent | acted
    if cfg.still_unacted:  # seen still, and at rest in its particle before or on a support where
        # it is seen: no one moved it, its particle's physics did (no events); one held still in
        # the air is held
        still = detected & model.dynamic & mem.seen_still
        silent = silent | (still[None, :] & (np.isfinite(state.holds[..., REF_Z]) | supported))
    # objects let go behind cover were let go back then, out of view (release_t)
    release_codes = dropped_behind_cover(move.release_codes, move.behind_cover, move.poses, out.poses, out.aabbs,
                                         model.scene.floor)
    ev = update_events(state.holds, acted, silent, Switches(
        move.modes, after_physics, new_modes, release_codes, supported,
        supported & (np.linalg.norm(out.velocities[..., :3], axis=-1) < rule.rest_speed), move.poses[..., 2],
        out.poses[..., 2], seen_z(model, t, detected),
        np.where((onset >= t - cfg.event_window) & (onset <= t), onset, t), let_go_t=t - hr.place_dwell,
        release_t=move.cover_t, rolled_off=None if move.fall is None else move.fall.mask[None, :]), t, rule)
    # taken in hand while still seen at rest, then seen to start moving: the Pick is that start
    codes, times, holds = late_picks(ev.codes, ev.times, ev.holds, is_held(ev.modes), onset, quiet,
                                     t - cfg.event_window, t)
    set_moving = move.set_moving
    if unheld is not None:  # those at rest in their particle before: set moving by an agent nobody tracks
        at_rest = np.linalg.norm(state.velocities[..., :3], axis=-1) < rule.rest_speed
        fresh = np.isfinite(onset) & (onset >= t - dt - hr.place_dwell)  # it just started moving, not
        started = unheld & at_rest & is_free(move.previous_modes) & fresh[None, :]  # a drift of physics
        set_moving = started if set_moving is None else (set_moving | started)
    if set_moving is not None:  # set moving by an agent nobody tracks: a Push when it began
        pushed = set_moving & is_free(ev.modes) & (codes == 0)
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
        model.roll_released(velocities, unheld, np.ones_like(unheld))
    released = is_held(after_physics) & is_free(ev.modes)
    if np.any(released):
        velocities = velocities.copy()
        model.roll_released(velocities, released, supported)
        # let go falling, off an edge (move.fall) or from a hand (the Release rule): at the speed
        # of the free fall through its last detections now, not the hand's (a ball seen falling
        # for 0.2 s falls at 2 m/s; let go at rest, it would land an update late)
        fell = released & (falling | (False if move.fall is None else move.fall.mask[None, :]))
        if cfg.moving_teleports and np.any(fell):
            vz_now = mem.free_fall((t,), cfg.physics.gravity, cfg.noise.position_std)[1][0]
            fell &= np.isfinite(vz_now)[None, :]
            velocities[..., 2] = np.where(fell, vz_now[None, :], velocities[..., 2])
    return Settled(out.poses, velocities, ev.modes, on_top, is_in, supported, codes, vel, holds, times)


def unheld_overrides(model, move: Move, out: BatchOutput, supported: np.ndarray, seen: np.ndarray,
                     tick_vel: np.ndarray) -> np.ndarray | None:
    """Entries ``(K, M)`` that physics switched to HELD in this update (free before, they diverged
    from their detection: Algorithm 1's override) of objects ``seen (M,)`` now moving along their
    support (tick velocity ``(M, 3)``, :func:`~estimator.model.motion.rolled_along`), ``supported (K,
    M)`` in their particle, that no tracked hand can reach (``Move.out_of_reach``; every object
    when no hand is tracked): a Pick needs an agent within reach, so they stay free (None: none;
    never in paper mode)."""
    if not model.config.moving_teleports:
        return None
    unreached = np.ones(model.M, dtype=bool) if move.out_of_reach is None else move.out_of_reach
    cand = (seen & unreached & model.dynamic & rolled_along(tick_vel)
            & moving_beyond_noise(model.memory, model.config.noise.position_std))
    if not np.any(cand):
        return None
    out_mask = is_free(move.modes) & is_held(out.modes) & cand[None, :] & supported
    return out_mask if np.any(out_mask) else None


def seen_z(model, t: float, detected: np.ndarray) -> np.ndarray:
    """Height ``(M,)`` (m) where each object detected since the last update is seen now: the lower
    of its latest detection and their mean over ``place_dwell`` (noise averaged, and an object
    that just fell is seen where it fell); NaN where not detected."""
    mean = model.memory.mean_positions(t, model.config.reasoner.place_dwell)[:, 2]
    return np.where(detected, np.fmin(model.memory.last_pose[:, 2], mean), np.nan)
