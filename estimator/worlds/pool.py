"""The particle worlds: one persistent copy of the scene per particle slot, the copies packed side by
side into a few pybullet clients (:class:`~physics.group.WorldGroup`), held in this process or
sharded over persistent worker processes. Workers and caller share the particles' input and output
arrays in one block of shared memory; the pipes carry only commands.

Memory and start-up follow the number of clients, not K: a client costs about 28 MB, a copy of a
tabletop scene a fraction of a megabyte. The slots are split into ``worlds`` contiguous groups, one
client each, by :func:`shard_bounds` of K alone; a worker holds whole groups. Slot ``k`` therefore
always lives in the same copy of the same client, whatever the number of workers, and a copy's
history depends only on the arrays it is given, so results do not depend on ``workers`` (see
DESIGN.md: contact caches survive pose resets, so a copy must not be shared between particle
slots).
"""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from physics.scene import CameraSpec, Scene
from physics.visibility import first_copies
from physics.world import PhysicsSettings

from .batch import PER_PARTICLE, BatchInput, BatchOutput
from .processes import worker_context
from .shard import _Shard, _worker_main
from .shared_batch import SharedBatch
from .world_cache import WorldCache

__all__ = ["BatchInput", "BatchOutput", "WorldPool", "shard_bounds"]

log = logging.getLogger(__name__)


def shard_bounds(n_particles: int, n_shards: int) -> list[tuple[int, int]]:
    """Contiguous, nearly equal slot ranges ``[(lo, hi), ...]`` for ``n_shards`` shards."""
    n_shards = max(1, min(n_shards, n_particles))
    edges = np.linspace(0, n_particles, n_shards + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


DEFAULT_WORLDS = 8
"""Default number of pybullet clients the particle slots are packed into."""


def interleaved_slots(groups: list[tuple[int, int]]) -> np.ndarray:
    """The slots of ``groups`` (contiguous ranges, one client each) in the order particles take them
    when their number changes: one slot of each client in turn (particle ``i`` in client ``i mod
    G``), so that any K particles are spread evenly over the clients, hence over the workers."""
    order = []
    for pos in range(max(hi - lo for lo, hi in groups)):
        order += [lo + pos for lo, hi in groups if lo + pos < hi]
    return np.array(order, dtype=int)


class WorldPool:
    """K particle worlds, packed into ``worlds`` pybullet clients (default ``min(K, 8)``; fixed by
    the caller, never by ``workers``, so that results do not depend on ``workers``). ``workers=0``
    keeps them in this process; otherwise ``min(workers, worlds)`` worker processes each own a
    contiguous run of clients. Use as a context manager or call :meth:`close`.

    After :meth:`run` (and :meth:`bare_step`), ``last_run_seconds`` is the wall time of the call in
    this process and ``last_worker_seconds`` the time each shard took in its worker, and after
    :meth:`run` ``last_worker_parts`` where each shard's time went and ``last_worker_counts`` what
    it moved (``_Shard.run``'s ``last_parts`` and ``last_counts``; the benchmark's breakdown). A
    worker process that dies (killed, out of memory) is restarted by the next :meth:`run`, which
    reports its particles as not finite (the caller re-seeds them) and counts it in ``restarts``;
    an exception inside a live worker is a ``RuntimeError``. ``scene_boxes (M, 2, 3)``: the
    objects' world AABBs (m) at the scene's poses, read when the worlds were built.

    ``max_particles`` (default: ``n_particles``, a fixed count): the pool holds slots for that many
    particles, and :meth:`run` takes any number of particles up to it. Particle ``i`` lives in slot
    ``slot_of[i]`` (:func:`interleaved_slots`: spread over the clients); a slot's copy is built the
    first time a run uses it, and parked while no particle uses it."""

    def __init__(self, scene: Scene, n_particles: int, workers: int = 0,
                 settings: PhysicsSettings | None = None, worlds: int | None = None,
                 max_particles: int | None = None):
        if n_particles < 1:
            raise ValueError(f"a world pool needs at least one particle, got {n_particles}")
        if worlds is not None and worlds < 1:
            raise ValueError(f"worlds must be >= 1, got {worlds}")
        if max_particles is not None and max_particles < n_particles:
            raise ValueError(f"max_particles ({max_particles}) must be >= n_particles ({n_particles})")
        n_slots = n_particles if max_particles is None else int(max_particles)
        self.n_particles, self.n_slots = n_particles, n_slots
        self.workers = workers
        settings = settings or PhysicsSettings()
        self.groups = shard_bounds(n_slots, min(n_slots, worlds or DEFAULT_WORLDS))
        self.slot_of = np.arange(n_slots) if max_particles is None else interleaved_slots(self.groups)
        self.cache = WorldCache()  # what each slot's world holds (advance and follow keep it told)
        self._used = self._slots_used(n_particles)
        self._local: _Shard | None = None
        self.last_run_seconds = 0.0
        self.last_worker_seconds: list[float] = []
        self.last_worker_parts: list[dict[str, float]] = []
        self.last_worker_counts: list[dict[str, int]] = []
        self._procs, self._conns, self._bounds = [], [], []
        self.restarts = 0
        if workers <= 0:
            self._local = _Shard(scene, settings, self.groups, self._used)
            self.initial_params, self.scene_boxes = self._local.initial_params(), self._local.scene_boxes
            return
        self._ctx = worker_context()  # forked from a server that has the worker's imports (processes)
        self._runs = [self.groups[a:b] for a, b in shard_bounds(len(self.groups), workers)]
        self._bounds = [(run[0][0], run[-1][1]) for run in self._runs]
        self._buffer = self._ctx.RawArray("b", SharedBatch.nbytes(n_slots, len(scene.objects)))
        self._shared = SharedBatch(self._buffer, n_slots, len(scene.objects))
        self._scene, self._settings = scene, settings
        try:
            for j in range(len(self._runs)):
                self._start_worker(j)
            params = [self._receive(c) for c in self._conns]
        except BaseException:
            self.close()
            raise
        self.initial_params, self.scene_boxes = params[0]

    def _start_worker(self, j: int) -> None:
        """Start (or restart) the worker process of shard ``j``; it answers with the initial
        parameters once its worlds are built."""
        parent, child = self._ctx.Pipe()
        lo, hi = self._bounds[j]
        p = self._ctx.Process(target=_worker_main, daemon=True,
                              args=(child, self._scene, self._settings, self._runs[j], self._buffer,
                                    self.n_slots, self._used[lo:hi]))
        p.start()
        child.close()
        if j < len(self._procs):
            self._conns[j].close()
            self._procs[j], self._conns[j] = p, parent
        else:
            self._procs.append(p)
            self._conns.append(parent)

    @staticmethod
    def _recv(conn) -> tuple[str, object]:
        try:
            return conn.recv()
        except (EOFError, OSError):
            return "dead", "the worker process died (killed, or out of memory?)"

    @classmethod
    def _receive(cls, conn):
        status, payload = cls._recv(conn)
        if status != "ok":
            raise RuntimeError(f"particle worker failed:\n{payload}")
        return payload

    def run(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False,
            moving: bool = False, cameras: tuple[CameraSpec, ...] | None = None,
            freeze: bool = False, sleep_loads: bool = False) -> BatchOutput:
        """Propagate all K particles by ``n_steps`` steps (see :func:`~estimator.worlds.propagate.propagate`;
        ``moving``: divergence tests of objects teleported in motion carry their target on at its
        velocity; ``freeze``: objects nothing can reach are out of collision while stepping;
        ``sleep_loads``: objects loaded at rest that end the update at rest are put to sleep);
        visibility of ``batch.vis_query`` to ``cameras`` (None: the scene's camera; several: the
        largest fraction any of them sees)."""
        t0 = time.perf_counter()
        K = len(batch.poses)
        if K > self.n_slots:
            raise ValueError(f"the pool holds {self.n_slots} particles, a run asked for {K}")
        self.n_particles, self._used = K, self._slots_used(K)
        slots = self.slot_of[:K]
        if self._local is not None:
            out = self._in_particle_order(self._local.run(self._by_slot(batch), self._used, n_steps, d_sim_perc,
                                                          lazy, moving, cameras, freeze, sleep_loads), slots)
            self.last_run_seconds = time.perf_counter() - t0
            self.last_worker_seconds = [self.last_run_seconds]
            self.last_worker_parts = [dict(self._local.last_parts)]
            self.last_worker_counts = [dict(self._local.last_counts)]
            return out
        self._shared.write_inputs(batch, slots)
        for conn, (lo, hi) in zip(self._conns, self._bounds):
            try:
                conn.send(("run", self._used[lo:hi], n_steps, d_sim_perc, lazy, moving, cameras, freeze, sleep_loads))
            except OSError:
                pass  # a dead worker: its reply says so
        replies = [self._recv(conn) for conn in self._conns]  # all of them: no reply is left unread
        for status, payload in replies:
            if status == "error":  # an exception in a live worker is a bug: report it
                raise RuntimeError(f"particle worker failed:\n{payload}")
        out = self._shared.outputs(slots)
        for j, (status, _) in enumerate(replies):
            if status == "dead":  # a worker that died: its particles are lost, the worker restarted
                lo, hi = self._bounds[j]
                log.warning("particle worker %d (slots %d-%d) died; restarting it, its particles are "
                            "re-seeded from the others", j, lo, hi - 1)
                lost = (self.slot_of[:K] >= lo) & (self.slot_of[:K] < hi)
                out.finite[lost] = False
                out.poses[lost], out.velocities[lost] = batch.poses[lost], 0.0
                out.modes[lost], out.visible[lost], out.aabbs[lost] = batch.modes[lost], 0.0, np.nan
                self._start_worker(j)
                self._receive(self._conns[j])
                self.restarts += 1
        self.last_run_seconds = time.perf_counter() - t0
        self.last_worker_seconds = [payload[0] if status == "ok" else 0.0 for status, payload in replies]
        self.last_worker_parts = [payload[1] if status == "ok" else {} for status, payload in replies]
        self.last_worker_counts = [payload[2] if status == "ok" else {} for status, payload in replies]
        return out

    def advance(self, batch: BatchInput, n_steps: int, d_sim_perc: float, lazy: bool = False,
                moving: bool = False, cameras: tuple[CameraSpec, ...] | None = None,
                fused: np.ndarray | None = None, freeze: bool = False, sleep_loads: bool = False,
                placed: np.ndarray | None = None) -> BatchOutput:
        """:meth:`run` for the particles' next update, the pool keeping its :attr:`cache` told: the
        entries of ``batch`` to load (``reset``) and those a world produced at rest (``settled``) are
        the cache's (:meth:`~estimator.worlds.world_cache.WorldCache.loads`; ``fused (K, M)``: entries only
        moved horizontally at rest), and what the worlds produce is remembered; an update of no
        steps produces nothing at rest but the entries ``placed (K, M)`` (placed at rest by the
        model, :func:`~estimator.model.regularisation.placed_at_rest`). Particles whose
        simulation exploded or whose worker died (``finite`` False) get back their state of ``batch``,
        at rest, and their worlds load in full at the next update."""
        reset, settled = self.cache.loads(batch.poses, batch.velocities, fused)
        out = self.run(dataclasses.replace(batch, reset=reset, settled=settled), n_steps, d_sim_perc, lazy,
                       moving, cameras, freeze, sleep_loads)
        bad = ~out.finite
        if np.any(bad):
            out.poses[bad] = batch.poses[bad]
            out.velocities[bad] = 0.0
            out.modes[bad] = batch.modes[bad]
        at_rest = None  # what the worlds produced; after loads only, what the model placed at rest
        if n_steps == 0:
            at_rest = np.zeros(out.modes.shape, dtype=bool) if placed is None else placed
        self.cache.hold(out.poses.copy(), out.velocities.copy(), bad, at_rest)
        return out

    def follow(self, ancestors: np.ndarray, at_rest: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Particle ``i`` is now a copy of particle ``ancestors[i]`` (``(n,)``: resampling, which may
        change their number); the worlds keep what they hold (:meth:`WorldCache.follow`, with its
        ``at_rest``; slots beyond ``n`` are parked at the next run)."""
        self.cache.follow(ancestors, at_rest)

    def _slots_used(self, K: int) -> np.ndarray:
        """``(n_slots,)`` bool: the slots of particles ``0 .. K-1``."""
        used = np.zeros(self.n_slots, bool)
        used[self.slot_of[:K]] = True
        return used

    def _by_slot(self, batch: BatchInput) -> BatchInput:
        """``batch`` (one row per particle) with one row per slot (rows of unused slots are zero)."""
        K, rows = len(batch.poses), self.slot_of[:len(batch.poses)]
        fields = []
        for name in PER_PARTICLE:
            value = getattr(batch, name)
            if value is None:
                fields.append(None)
                continue
            full = np.zeros((self.n_slots,) + value.shape[1:], dtype=value.dtype)
            full[rows] = value[:K]
            fields.append(full)
        return BatchInput(*fields, batch.vis_query)

    def _in_particle_order(self, out: BatchOutput, slots: np.ndarray) -> BatchOutput:
        """A shard's output (one row per slot in use, in increasing order of slot) in particle order."""
        rank = np.searchsorted(np.sort(slots), slots)
        return BatchOutput(*(getattr(out, f.name)[rank] for f in dataclasses.fields(BatchOutput)))

    def look(self, poses: np.ndarray, place: np.ndarray, targets: np.ndarray, cameras: tuple[CameraSpec, ...],
             threshold: float | None = None) -> np.ndarray:
        """Visible fractions ``(V, K, n)`` of objects ``targets (n,)`` to each of the V ``cameras``
        in every particle world, the objects ``place`` set at the particles' ``poses (K, M, 7)``
        (occlusion by everything each particle believes); with ``threshold``, bool: whether each
        reaches it. Particles equal in every pose share the answer of the first of them (each
        distinct one is looked at in its own world); the worlds are left as they were."""
        poses = np.asarray(poses, dtype=float)
        K = len(poses)
        if K != self.n_particles:
            raise ValueError(f"look: {K} particles' poses for a pool running {self.n_particles}")
        first = first_copies(poses)
        only = first == np.arange(K)
        rows = self.slot_of[:K]  # to one row per slot
        full = np.zeros((self.n_slots,) + poses.shape[1:])
        full[:, :, 6] = 1.0
        full[rows] = poses
        mask = np.zeros(self.n_slots, bool)
        mask[rows] = only
        poses, only = full, mask
        if self._local is not None:
            return self._local.look(poses, place, targets, tuple(cameras), threshold, only)[:, rows][:, first]
        for conn, (lo, hi) in zip(self._conns, self._bounds):
            conn.send(("look", poses[lo:hi], place, targets, tuple(cameras), threshold, only[lo:hi]))
        return np.concatenate([self._receive(conn) for conn in self._conns], axis=1)[:, rows][:, first]

    def bare_step(self, n_steps: int, resting: bool = True) -> None:
        """Step every world ``n_steps`` times, with the same sharding and nothing else;
        ``last_worker_seconds`` is then each shard's stepping time. ``resting=False``: with the
        objects at rest out of collision detection (:meth:`_Shard.bare_step
        <estimator.worlds.shard._Shard.bare_step>`; save and restore the worlds around it)."""
        if self._local is not None:
            self.last_worker_seconds = [self._local.bare_step(n_steps, resting)]
            return
        for conn in self._conns:
            conn.send(("bare", n_steps, resting))
        self.last_worker_seconds = [self._receive(conn) for conn in self._conns]

    def save(self) -> None:
        """Save the state of every particle world (to be put back by :meth:`restore`; the benchmark
        steps the worlds between the two)."""
        self._command("save")

    def restore(self) -> None:
        """Put every particle world back in the state of the last :meth:`save`."""
        self._command("restore")

    def _command(self, name: str) -> None:
        if self._local is not None:
            getattr(self._local, name)()
            return
        for conn in self._conns:
            conn.send((name,))
        for conn in self._conns:
            self._receive(conn)

    @property
    def shard_sizes(self) -> list[int]:
        """Number of particle worlds in use in each worker (one entry, K, in this process)."""
        return [int(self._used[lo:hi].sum()) for lo, hi in self._bounds] or [self.n_particles]

    def worker_pids(self) -> list[int]:
        return [p.pid for p in self._procs]

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            self._local = None
        for conn in self._conns:
            try:
                conn.send(("close",))
            except (OSError, BrokenPipeError):
                pass
        for p in self._procs:
            p.join(timeout=5)
            if p.is_alive():
                p.terminate()
        for conn in self._conns:
            conn.close()
        self._procs, self._conns = [], []

    def __enter__(self) -> "WorldPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
