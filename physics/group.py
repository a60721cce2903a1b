"""Several copies of one scene side by side in one pybullet client.

A DIRECT client costs about 28 MB whatever it holds (DESIGN.md's measurement on these machines); a
copy of a tabletop scene in an existing client costs far less (with collision-only URDFs,
:mod:`physics.urdf`). A :class:`WorldGroup` puts ``copies`` copies of a scene
in one client, on a grid :data:`SPACING` metres apart (far beyond any camera's reach and any object's
travel, so that copies never meet), each a :class:`~physics.world.World` with its own ``origin``:
named, array-based access in its own scene frame, as if it were alone. They share the floor plane
and the engine settings; one ``stepSimulation`` advances them all.

Each copy's simulation depends only on its own bodies and their history, and the group's layout is
fixed by ``copies``: a particle that always lives in the same copy of the same group gives the same
results whatever process holds the group.
"""
from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from .scene import Scene
from .world import PhysicsSettings, World, connect

SPACING = 200.0
"""Distance (m) between neighbouring copies of a scene in a shared client."""


class WorldGroup:
    """``copies`` copies of ``scene`` in one DIRECT client: ``worlds[g]`` is copy ``g``.

    ``capacity`` (default ``copies``): the most copies the group will hold; the grid of origins is
    laid out for it, so that copies added later by :meth:`grow` take the places they would have had
    if built at once. Use as a context manager or call :meth:`close` (which disconnects the client)."""

    def __init__(self, scene: Scene, settings: PhysicsSettings | None = None, copies: int = 1,
                 capacity: int | None = None):
        if copies < 1:
            raise ValueError(f"a world group needs at least one copy, got {copies}")
        capacity = copies if capacity is None else int(capacity)
        if capacity < copies:
            raise ValueError(f"a world group's capacity ({capacity}) must be >= its copies ({copies})")
        self.scene, self.capacity = scene, capacity
        self.settings = settings or PhysicsSettings()
        self.client, floor_uid = connect(self.settings, scene.floor)
        # every island of contacts is solved alone (pybullet merges small ones by default): a copy's
        # solver then stops at its own residual, whatever its neighbours do (and steps ~10 % faster)
        pb.setPhysicsEngineParameter(minimumSolverIslandSize=1, physicsClientId=self.client)
        self.worlds: list[World] = []
        self._floor_uid = floor_uid
        self._shapes: dict[int, int] = {}  # the copies share their primitives' collision shapes
        try:
            self.grow(copies)
        except BaseException:
            self.close()
            raise

    def grow(self, copies: int) -> list[World]:
        """Add copies until the group holds ``copies`` (at most its capacity); returns those added.
        A copy added later is the copy that would have been built at once (same place, same
        bodies, its objects parked until loaded)."""
        if copies > self.capacity:
            raise ValueError(f"a world group of capacity {self.capacity} cannot hold {copies} copies")
        cols = math.ceil(math.sqrt(self.capacity))
        added = []
        for g in range(len(self.worlds), copies):
            origin = (SPACING * (g % cols), SPACING * (g // cols), 0.0)
            added.append(World(self.scene, self.settings, client=self.client, origin=origin,
                               floor_uid=self._floor_uid, shapes=self._shapes))
            self.worlds.append(added[-1])
        return added

    @property
    def origins(self) -> np.ndarray:
        """Origins ``(G, 3)`` (m) of the copies' scene frames in the client."""
        return np.array([w.origin for w in self.worlds])

    # the client's stepping and state are every copy's: its first copy's methods serve for all
    def step(self, n: int = 1) -> None:
        """Advance every copy by ``n`` fixed steps."""
        self.worlds[0].step(n)

    def save_state(self) -> int:
        """Save the state of every copy; returns an id for :meth:`restore_state`."""
        return self.worlds[0].save_state()

    def restore_state(self, state_id: int) -> None:
        self.worlds[0].restore_state(state_id)

    def remove_state(self, state_id: int) -> None:
        self.worlds[0].remove_state(state_id)

    def close(self) -> None:
        """Disconnect the client. Safe to call twice."""
        for w in self.worlds:
            w.close()
        if self.client >= 0:
            try:
                pb.disconnect(physicsClientId=self.client)
            except pb.error:
                pass
            self.client = -1

    def __enter__(self) -> "WorldGroup":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
