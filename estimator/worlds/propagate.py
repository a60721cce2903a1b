"""Advance one particle's world through one update: Algorithm 1 of the physics reasoner.

This is the hot path, run in the worker that owns the world. It takes and returns plain arrays so that
worker processes exchange only numpy data. One call simulates ``n_steps`` fixed steps and, at every
step:

* HELD objects move to their target pose (the perception, a tracked hand, or where they were last
  seen): smoothly over the update for objects held from its start (physics moves what they carry),
  at once, with their contents carried rigidly, for objects that become held during it;
* FREE objects that are checked (perceived, dynamic) and whose simulated position diverges from the
  perceived one by more than ``d_sim_perc`` switch to HELD (they are not physically plausible: an agent
  must be moving them) and are overridden from that step on.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pybullet as pb

from actions.modes import HELD, is_free, is_held
from physics.sleep import asleep, near, touching, wake

from . import resting
from .batch import PER_PARTICLE, BatchInput, BatchOutput, ParticleWorld, StepInput, StepOutput, assemble
from .frozen import to_freeze
from .held import HeldObjects, depenetrate, held_glides
from .resting import PROBE_STEPS, SETTLED_REACH, restart_after_wake, sleep_resting, sleep_settling, sleep_still, slow

MAX_SPEED = 50.0  # m/s: anything faster is a simulation that exploded


A_MAX = 9.81
"""Bound on an object's acceleration (m/s^2) between two divergence tests when checks are lazy:
gravity's, the only force that acts without a contact (an object in flight, sliding or rolling
down a slope accelerates at most this much; one pushed or hit may exceed it and is then tested a
few steps late, at the latest after the last step)."""


def propagate(pw: ParticleWorld, inp: StepInput, n_steps: int, d_sim_perc: float,
              lazy: bool = False, moving: bool = False, freeze: bool = False,
              sleep_loads: bool = False) -> StepOutput:
    """Run Algorithm 1 for ``n_steps`` steps in one particle's world (see :func:`propagate_batch`)."""
    batch = BatchInput(*(None if getattr(inp, f) is None else np.asarray(getattr(inp, f))[None]
                         for f in PER_PARTICLE))
    out = propagate_batch([pw], batch, n_steps, d_sim_perc, lazy, moving, freeze=freeze, sleep_loads=sleep_loads)
    return StepOutput(out.poses[0], out.velocities[0], out.modes[0], out.max_divergence[0], out.aabbs[0],
                      bool(out.finite[0]))


PARTS = ("prepare", "load", "step", "held and tests", "read", "finish")
"""The parts of :func:`propagate_batch`'s time: the array work before the worlds (``prepare``);
per client, setting parameters, loading states, waking what they touch, pushing out of penetration
and setting up the held objects (``load``); Bullet's steps (``step``); the rest of the step loop:
moving held objects, divergence tests (``held and tests``); reading the state back (``read``);
assembling the output, the tests after the last step, putting resting objects to sleep
(``finish``)."""


LAST_STEPS = 2
"""With lazy tests, a test that falls due in the last this many steps of an update is left to the
test after the last step (at most this many steps late)."""


def _due_steps(d: np.ndarray, v: np.ndarray, d_sim_perc: float, dt: float) -> np.ndarray:
    """First step (>= 1) at which an object at divergence ``d`` (m) moving at ``v`` (m/s) and
    accelerating at most at :data:`A_MAX` could have crossed ``d_sim_perc``."""
    room = np.maximum(d_sim_perc - d, 0.0)
    tau = (-v + np.sqrt(v * v + 2.0 * A_MAX * room)) / A_MAX
    return np.maximum(1, (tau / dt).astype(np.int64))


def propagate_batch(pws: list[ParticleWorld], batch: BatchInput, n_steps: int, d_sim_perc: float,
                    lazy: bool = False, moving: bool = False, parts: dict[str, float] | None = None,
                    counts: dict[str, int] | None = None, freeze: bool = False,
                    sleep_loads: bool = False) -> BatchOutput:
    """Run Algorithm 1 for ``n_steps`` steps in each of the K worlds ``pws`` (all built from the same
    scene), particle ``k`` from the state in row ``k`` of ``batch``.

    Worlds that share a pybullet client (copies of a :class:`~physics.group.WorldGroup`) are stepped
    together, one ``stepSimulation`` per step for all of them; ``pws`` must then hold every copy of
    their client (the others would be stepped too).

    With ``lazy=False`` the divergence of every free perceived object is tested after every step, as
    the paper does. With ``lazy=True`` an object is tested again only at the first step at which,
    starting from its present divergence ``d`` and speed ``v`` and accelerating at most at
    :data:`A_MAX`, it could have crossed ``d_sim_perc``, and after the last step: exact for objects
    moving freely or resting, late by a few steps only when something hits an object hard.

    With ``moving=True`` a tested object's target moves at its ``target_vel`` (linear part) through
    the update and reaches ``target`` at its end: an object started where its detection was at the
    update's start, with its perceived velocity, is compared with that detection carried along, not
    with a fixed point (objects whose target velocity is zero are tested against their fixed target,
    as always); one that diverges and becomes held follows the moving target.

    With :attr:`PhysicsSettings.sleeping`, what an update moves (loads, held objects, pushes out of
    penetration) is woken together with everything that touched it, and free objects at rest at both
    ends of the update are put to sleep (:data:`~estimator.worlds.resting.REST_SPEED`).

    Array work is done once for the K worlds (frame conversions, first test steps, the finiteness
    test); each client's loop is plain Python around direct pybullet calls. A world's result depends
    only on its own row of ``batch`` and its own history, so that sharding whole clients over
    processes does not change any output. Returns a :class:`BatchOutput` whose ``visible`` is all
    zeros.

    With ``freeze=True`` (and sleeping), objects at rest that nothing awake can reach during the
    update (:func:`~estimator.worlds.frozen.unreachable`) are out of collision detection while the
    worlds step, and stay out until an update may reach them or rays are cast
    (:meth:`~estimator.worlds.batch.ParticleWorld.thaw`: the caller's duty before any ray test).
    Objects at rest at both ends of the update are put to sleep
    (:func:`~estimator.worlds.resting.sleep_resting`): those it did not load, and with
    ``sleep_loads=True`` also those it loaded (teleported, resampled, pushed out of penetration)
    unless held at its start; with it, those it loaded or woke at rest (in a world never stepped,
    all) that are still after :data:`~estimator.worlds.resting.PROBE_STEPS` steps, or slow and not
    sped up after twice that many, sleep from then on (:func:`~estimator.worlds.resting.sleep_still`,
    :func:`~estimator.worlds.resting.sleep_settling`; updates of fewer than three times that many
    steps are not probed). In a world never stepped, the ``settled`` entries are at rest by the
    model's word (:func:`~estimator.model.regularisation.placed_at_rest`): they sleep from the first
    step (:func:`~estimator.worlds.resting.sleep_as_loaded`), unprobed, and may be frozen.

    ``parts``: where the call's time goes is added to it (seconds, :data:`PARTS`). ``counts``: what
    the update moved is added to it: ``entries`` (worlds times dynamic objects), ``moved`` (the
    entries it loaded awake, held or pushed out of penetration), ``moving`` (those not at rest at
    its end, :func:`~estimator.worlds.resting.slow`) and ``frozen``.
    """
    clock = time.perf_counter
    t_part = clock()
    K = len(pws)
    if K == 0:
        raise ValueError("propagate_batch needs at least one world")
    w0 = pws[0].world
    M = w0.num_objects
    if batch.poses.shape != (K, M, 7):
        raise ValueError(f"batch.poses must have shape ({K}, {M}, 7), got {batch.poses.shape}")
    dyn = pws[0].dynamic
    dt = w0.settings.time_step
    sleeping = w0.settings.sleeping
    n_steps = int(n_steps)
    dyn_mask = np.zeros(M, dtype=bool)
    dyn_mask[dyn] = True
    modes_out = batch.modes.copy()
    origins = np.array([pw.world.origin for pw in pws])[:, None, :]  # (K, 1, 3): scene -> client frame
    # loads: centre-of-mass poses and velocities of the entries to reset, in the client frame
    reset = np.broadcast_to(dyn_mask, (K, M)) if batch.reset is None else batch.reset & dyn_mask
    com_p, com_v = w0.com_frame(batch.poses, batch.velocities)
    com_p = np.array(com_p)
    com_p[..., :3] += origins
    held_mask = is_held(batch.modes) & dyn_mask
    depen_mask = batch.depenetrate & dyn_mask
    moved = reset | held_mask | depen_mask
    settled = placed = np.zeros((K, M), dtype=bool)
    stepped = np.array([pw.stepped for pw in pws])[:, None]  # loaded at rest and never stepped: awake
    if batch.settled is not None:  # a settled state loaded asleep stays asleep...
        settled = batch.settled & ~held_mask & ~depen_mask
        placed = settled & ~stepped if sleeping and n_steps > 0 else placed  # (in a world never stepped: put so)
        settled &= moved
        moved &= ~settled
    reset_l, depen_l, moved_l, held_l = reset.tolist(), depen_mask.tolist(), moved.tolist(), held_mask.tolist()
    placed_l = placed.tolist() if placed.any() else None  # (only before a world's first step)
    probing = sleep_loads and sleeping and n_steps >= 3 * PROBE_STEPS
    early = [0]  # bodies put to sleep after the probe's steps
    reset_any = reset.any(axis=1).tolist()
    settled_l = (settled | placed).tolist() if placed_l else settled.tolist()  # asleep as loaded, or placed so
    # watched objects and the first step at which each one needs testing
    checked = batch.check & is_free(batch.modes) & dyn_mask
    tvel = np.where(checked[..., None], batch.target_vel[..., :3], 0.0) if moving else np.zeros((K, M, 3))
    # where each target is at the update's start: a moving target reaches its pose at the end
    target_com, target_orn = np.split(w0.com_frame(batch.target)[0], [3], axis=-1)
    target_com = target_com + origins - tvel * (n_steps * dt)
    due = np.ones((K, M), dtype=np.int64)
    if lazy:
        d0 = np.linalg.norm(com_p[..., :3] - target_com, axis=-1)
        due = _due_steps(d0, np.linalg.norm(com_v[..., :3] - tvel, axis=-1), d_sim_perc, dt)
    checked_l, target_l, due_l, tvel_l = checked.tolist(), target_com.tolist(), due.tolist(), tvel.tolist()
    frozen = alone = np.zeros((K, M), dtype=bool)
    if freeze and sleeping and n_steps > 0:
        held_before = np.stack([pw.held for pw in pws])  # let go since (held still: moved): not asleep yet
        frozen, alone = to_freeze(pws[0].boxes, com_p, com_v, target_com, tvel, target_orn, checked, held_mask,
                                  moved | held_before | (reset & ~settled) | (~stepped & ~placed), dyn_mask,
                                  n_steps * dt, d_sim_perc, w0.settings.gravity,
                                  w0.static_raw()[1][~dyn_mask][None] + origins[:, None],
                                  origins[:, 0, 2] if w0.floor_uid >= 0 else None)
    frozen_l = frozen.tolist()
    glides = held_glides([pw.world for pw in pws], batch.poses, batch.target, held_mask, alone, n_steps)
    clients: dict[int, list[int]] = {}
    for k, pw in enumerate(pws):
        clients.setdefault(pw.world.client, []).append(k)
    tested: list[tuple[int, int, float]] = []  # (particle, object, largest divergence) of in-loop tests
    switched_at: list[tuple[int, int, float]] = []
    read: list[tuple[list, list, list]] = [([], [], [])] * K
    speed_l = np.any(com_v != 0.0, axis=-1).tolist()
    took = dict.fromkeys(PARTS, 0.0)
    took["prepare"] = clock() - t_part
    for client, ks in clients.items():
        t_part = clock()
        helds, watches, restart, probes = [], [], [], []
        for k in ks:
            pw = pws[k]
            w = pw.world
            if pw.frozen:  # frozen at the last update: back in collision unless frozen again
                pw.thaw([i for i in pw.frozen if not frozen_l[k][i]])
            rows = [i for i in dyn if moved_l[k][i]] if True in moved_l[k] else []
            woken = rows + touching(w, rows) if sleeping and rows else []  # contacts before the reset
            if woken and pw.contactless:  # contacts a freeze made Bullet forget: the boxes that touch
                stale = pw.contactless if pw.contactless.isdisjoint(rows) else None
                woken += [j for j in near(w, rows, 0.0) if (stale is None or j in stale) and j not in woken]
            if True in reset_l[k]:
                loads = [i for i in dyn if reset_l[k][i]]
                if sleeping and n_steps > 0:
                    restart += restart_after_wake(w, asleep(w, [i for i in loads if speed_l[k][i]]), com_p[k],
                                                  com_v[k], dt, w0.settings.gravity)
                row_p, row_v = com_p[k].tolist(), com_v[k].tolist()  # lists, once
                w.load_com_state(loads, [row_p[i] for i in loads], [row_v[i] for i in loads])
            if woken:
                wake(w, woken)
            if True in depen_l[k]:
                depenetrate(w, [i for i in dyn if depen_l[k][i]])
            if rows and True in settled_l[k]:  # ...unless something moved is (or was) near it
                near_settled = [i for i in near(w, rows, SETTLED_REACH) if settled_l[k][i]]
                wake(w, near_settled)
                woken += near_settled
            asleep_now = [i for i in dyn if placed_l[k][i] and i not in woken] if placed_l and True in placed_l[k] \
                else []
            if asleep_now:  # placed at rest in a world never stepped, and nothing loaded near woke it
                restart += resting.sleep_as_loaded(w, asleep_now, com_p[k])
            if True in frozen_l[k]:
                fz = [i for i in dyn if frozen_l[k][i] and i not in woken and not w.is_parked(i)]
                if True in reset_l[k]:  # a settled load (not woken by its load): asleep, for sure
                    slept = [i for i in fz if reset_l[k][i] and i not in asleep_now]
                    restart += resting.sleep_as_loaded(w, slept, com_p[k])
                pw.thaw([i for i in pw.frozen if i not in fz])  # woken since
                w.set_colliding([i for i in fz if i not in pw.frozen], False)
                pw.frozen = fz
                pw.contactless.update(fz)
            pw.contactless.difference_update(woken)
            pw.apply_params(batch.params[k], pw.frozen)
            if probing:  # awake at rest, from loads or wakes (in a world never stepped, everything): probed
                fresh = woken if pw.stepped else [i for i in dyn if not w.is_parked(i) and i not in asleep_now]
                probes += [w.uids[i] for i in fresh if not speed_l[k][i] and not held_l[k][i]]
            held = HeldObjects(w, target_l[k], target_orn[k], batch.target_vel[k], batch.contents[k], n_steps, moving)
            for h in glides.get(k, ()):
                held.glide(*h)
            helds.append(held)
            # [index, body id, x, y, z of the perceived centre of mass, next step to test, largest
            # divergence, position of the world in ks, velocity of the target x, y, z]
            watches += [[i, w.uids[i], *target_l[k][i], due_l[k][i], 0.0, len(helds) - 1, *tvel_l[k][i]]
                        for i in dyn if checked_l[k][i] and not (lazy and i in pw.frozen)]  # frozen: tested at the end
        stepping = [0.0] if parts is not None else None  # Bullet's steps timed one by one only when asked
        t_sim = clock()
        took["load"] += t_sim - t_part
        switched = _simulate(client, dt, helds, watches, n_steps, d_sim_perc, lazy, restart, stepping, probes,
                             early)
        t_part = clock()
        bullet = stepping[0] if stepping else 0.0
        took["step"] += bullet
        took["held and tests"] += t_part - t_sim - bullet
        switched_at += [(ks[j], i, d) for j, i, d in switched]
        tested += [(ks[item[7]], item[0], item[6]) for item in watches if item[6]]
        for k in ks:  # what was frozen and not loaded has not moved since this world's last read
            read[k] = pws[k].read({i for i in pws[k].frozen if not reset_l[k][i]})
        for k in ks:
            pws[k].stepped = n_steps > 0 or (pws[k].stepped and not reset_any[k])
        took["read"] += clock() - t_part
    t_part = clock()
    poses, vel, aabbs = assemble(w0, dyn, read, origins)
    # largest divergences: from the tests in the loop and, lazily, the test after the last step on
    # the state read back (an object that diverged during the last steps is held, at the
    # perception, as in the loop)
    max_d = np.zeros((K, M))
    if tested:
        kk, ii, dd = zip(*tested)
        max_d[list(kk), list(ii)] = dd
    still = checked.copy()
    for k, i, _ in switched_at:
        still[k, i] = False
        modes_out[k, i] = HELD
    if lazy and n_steps > 0 and still.any():
        d_end = np.where(still, np.linalg.norm(poses[..., :3] - target_com - tvel * (n_steps * dt), axis=-1), 0.0)
        np.maximum(max_d, d_end, out=max_d)
        for k in np.flatnonzero((d_end > d_sim_perc).any(axis=1)).tolist():
            late = np.flatnonzero(d_end[k] > d_sim_perc).tolist()
            modes_out[k, late] = HELD
            w = pws[k].world
            HeldObjects(w, target_l[k], target_orn[k], batch.target_vel[k], batch.contents[k], n_steps, moving).jump(late)
            p, v, b = assemble(w0, dyn, [pws[k].read()], origins[k:k + 1])
            poses[k], vel[k], aabbs[k] = p[0], v[0], b[0]
    for k, i, d in switched_at:
        max_d[k, i] = d
    held_out = is_held(modes_out) & dyn_mask  # what each world holds at the end (ParticleWorld.held)
    for pw, row in zip(pws, held_out):
        pw.held = row
    if sleeping:
        sleep_resting(pws, dyn_mask & is_free(modes_out) & ~(held_mask if sleep_loads else moved), com_v, vel)
    finite = (np.isfinite(poses).all(axis=(1, 2)) & np.isfinite(vel).all(axis=(1, 2))
              & (np.abs(vel[..., :3]) < MAX_SPEED).all(axis=(1, 2)))
    aabbs[~finite] = np.nan
    poses[..., :3] -= origins
    aabbs -= origins[:, None]
    poses, vel = w0.link_frame(poses, vel)
    took["finish"] = clock() - t_part
    if counts is not None:
        for name, n in (("entries", K * len(dyn)), ("moved", int(moved.sum())), ("slept early", early[0]),
                        ("moving", int((~slow(vel[:, dyn]) & finite[:, None]).sum())), ("frozen", int(frozen.sum()))):
            counts[name] = counts.get(name, 0) + n
    if parts is not None:
        for name, seconds in took.items():
            parts[name] = parts.get(name, 0.0) + seconds
    return BatchOutput(poses, vel, modes_out, max_d, aabbs, finite, np.zeros((K, M)))


def _simulate(client: int, dt: float, helds: list["HeldObjects"], watch: list[list], n_steps: int,
              d_sim_perc: float, lazy: bool, restart: list[tuple] = (),
              stepping: list[float] | None = None, probes: list[int] = (),
              slept: list[int] | None = None) -> list[tuple[int, int, float]]:
    """The step loop of one client (the hot path, plain Python), for its worlds' held objects
    ``helds`` (one per world) and divergence tests ``watch`` (items updated in place); ``restart``
    (see :func:`~estimator.worlds.resting.restart_after_wake`) is applied after the first step. Returns the objects that switched to
    HELD during the loop as ``(world position, object, largest divergence)`` (lazily, the test
    after the last step is left to the caller, on the state read back). ``stepping``: Bullet's
    stepping time is added to its one entry (seconds). ``probes``: body ids put to sleep after
    :data:`~estimator.worlds.resting.PROBE_STEPS` steps if slower than the rest thresholds times
    ``PROBE_STEPS / n_steps``, or after twice that many if slower than the thresholds and not sped
    up since (:func:`~estimator.worlds.resting.sleep_still`,
    :func:`~estimator.worlds.resting.sleep_settling`); their number is added to ``slept[0]``."""
    c = client
    get = pb.getBasePositionAndOrientation
    get_vel = pb.getBaseVelocity
    step = pb.stepSimulation
    if stepping is not None:
        clock, bullet_step = time.perf_counter, pb.stepSimulation

        def step(physicsClientId: int) -> None:
            t0 = clock()
            bullet_step(physicsClientId=physicsClientId)
            stepping[0] += clock() - t0
    out: list[tuple[int, int, float]] = []
    settling: list[tuple[int, float, float]] = []  # probed once, slow but not still: probed again
    slept = [0] if slept is None else slept
    moving = [h for h in helds if h.items]
    s = 0
    while s < n_steps:
        # step, with no test, up to the next step at which one is due
        stop = min(min(item[5] for item in watch), n_steps) if watch else n_steps
        if lazy and stop > n_steps - LAST_STEPS:
            stop = n_steps  # a test due in the last steps is the test after the last step
        if restart:
            stop = 1
        if (probes or settling) and s < 2 * PROBE_STEPS:  # stop at the probes' steps
            stop = min(stop, PROBE_STEPS if s < PROBE_STEPS else 2 * PROBE_STEPS)
        if moving:
            for t in range(s + 1, stop + 1):
                for h in moving:
                    h.apply(t)
                step(physicsClientId=c)
        else:
            for _ in range(stop - s):
                step(physicsClientId=c)
        s = stop
        if probes and s == PROBE_STEPS:
            settling, probes = sleep_still(c, probes, PROBE_STEPS / n_steps, slept), ()
        elif settling and s == 2 * PROBE_STEPS:
            sleep_settling(c, settling, slept)
            settling = []
        if restart:
            for uid, pos, orn, lin, ang in restart:
                pb.resetBasePositionAndOrientation(uid, pos, orn, physicsClientId=c)
                pb.resetBaseVelocity(uid, lin, ang, physicsClientId=c)
            restart = ()
        if lazy and s == n_steps:
            break  # the caller tests after the last step, on the state it reads back
        switched = None
        for item in watch:
            if item[5] > s:
                continue
            p = get(item[1], physicsClientId=c)[0]
            ts = s * dt  # the target moves on at its velocity (zero but with moving targets)
            d = math.sqrt((p[0] - item[2] - item[8] * ts) ** 2 + (p[1] - item[3] - item[9] * ts) ** 2
                          + (p[2] - item[4] - item[10] * ts) ** 2)
            if d > item[6]:
                item[6] = d
            if d > d_sim_perc:
                switched = switched or []
                switched.append(item)
            elif lazy:
                v = get_vel(item[1], physicsClientId=c)[0]
                vx, vy, vz = v[0] - item[8], v[1] - item[9], v[2] - item[10]  # relative to the target
                speed = math.sqrt(vx * vx + vy * vy + vz * vz)
                # steps k with d + speed * k dt + A_MAX (k dt)^2 / 2 <= d_sim_perc are safe
                tau = (-speed + math.sqrt(speed * speed + 2.0 * A_MAX * (d_sim_perc - d))) / A_MAX
                item[5] = s + max(1, int(tau / dt))
            else:
                item[5] = s + 1
        if switched:
            for j in sorted({item[7] for item in switched}):
                helds[j].jump([item[0] for item in switched if item[7] == j], s)
                if helds[j] not in moving:
                    moving.append(helds[j])
            out += [(item[7], item[0], item[6]) for item in switched]
            watch[:] = [item for item in watch if item not in switched]
    for h in helds:
        h.apply(n_steps + 1)  # held objects end the update exactly at their target
    return out
