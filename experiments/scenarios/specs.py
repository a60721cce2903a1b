"""A scenario's frozen records: :class:`Scenario` and its parts (the scripted hand, :class:`HandSpec`,
and its timed :class:`Waypoint` entries; the torso; the randomisation ranges), as
:func:`~experiments.scenarios.parsing.scenario_from_dict` makes them. Units: metres, kilograms,
seconds, degrees (the file format: :mod:`experiments.scenarios`)."""
from __future__ import annotations

from dataclasses import dataclass, field

from experiments.simulation.perception import PerceptionConfig
from physics.scene import Scene


@dataclass(frozen=True)
class HandTarget:
    """Where a waypoint sends the hand: ``position`` (absolute, m), or ``object`` + ``offset`` (the
    object's position when the motion starts, plus an offset in world axes), or ``by`` (relative to
    the previous waypoint)."""

    position: tuple[float, float, float] | None = None
    object: str | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    by: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Waypoint:
    """One timed step of the hand script. ``t`` (s) is when the hand reaches ``to`` (``None``: it
    stays) with orientation ``rpy_deg`` (``None``: unchanged); then ``grasp`` / ``release`` an object
    and switch ``collide`` (whether the hand pushes objects)."""

    t: float
    to: HandTarget | None = None
    rpy_deg: tuple[float, float, float] | None = None
    grasp: str | None = None
    release: str | None = None
    collide: bool | None = None


@dataclass(frozen=True)
class HandSpec:
    """The scripted hand: a sphere of ``radius`` (m) and ``mass`` (kg), driven towards its target by a
    constraint of at most ``max_force`` (N)."""

    start: tuple[float, float, float]
    script: tuple[Waypoint, ...] = ()
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.035
    mass: float = 1.0
    max_force: float = 500.0
    holding: str | None = None
    collide: bool = False


@dataclass(frozen=True)
class TorsoSpec:
    """A box (full ``size``, m) at ``position`` standing for the human's body: it occludes the camera
    but collides with nothing."""

    size: tuple[float, float, float]
    position: tuple[float, float, float]


@dataclass(frozen=True)
class ObjectRandomization:
    """Ranges ``(lo, hi)`` drawn uniformly for one object (see :mod:`experiments.scenarios`)."""

    id: str
    position: tuple[tuple[float, float], ...] | None = None
    yaw_deg: tuple[float, float] | None = None
    size: tuple[float, float] | None = None
    mass: tuple[float, float] | None = None
    friction: tuple[float, float] | None = None
    rolling_friction: tuple[float, float] | None = None
    spinning_friction: tuple[float, float] | None = None
    restitution: tuple[float, float] | None = None


@dataclass(frozen=True)
class Randomization:
    objects: tuple[ObjectRandomization, ...] = ()
    time_scale: tuple[float, float] = (1.0, 1.0)
    delay: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario file (nominal values; :func:`experiments.simulation.simulator.sample_variant` draws a
    seeded variant)."""

    name: str
    scene: Scene
    duration: float
    description: str = ""
    settle: float = 0.3
    hand: HandSpec | None = None
    torso: TorsoSpec | None = None
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    randomize: Randomization = field(default_factory=Randomization)
    source: str | None = None
    builtin: bool = False
