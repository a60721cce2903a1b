"""The set-ups of the independent recordings (:mod:`experiments.independent`): their bodies, the
hand's script, durations and tracker noise, the table and the camera they share. Units: metres,
kilograms, seconds, degrees. Like :mod:`experiments.independent`, nothing here imports the estimator
or the project's simulator.

Recordings (:data:`RECORDINGS`):

* ``flicked_ball``: a ball flicked along the table (no hand anywhere) rolls behind a box and stops
  there, on the table;
* ``ball_over_bin``: a hand carries a ball over an open bin, lets go, and stays still, tracked and in
  view; the ball falls into the bin, out of the camera's view;
* ``mug_over_edge``: a hand carries a mug past the table's edge, lets go and stays still in view;
  the mug falls to the floor behind the table;
* ``box_shoved``: a palm shoves a box along the table (never lifting it) until it is hidden behind a
  screen, then leaves, empty.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

TABLE_TOP = 0.625
"""m: height of the table top in every recording (a 1.5 x 1.0 m slab 5 cm thick, top at 0.625 m)."""

CAMERA = {"position": [1.3, 0.0, 1.25], "target": [0.0, 0.0, 0.65], "fov_deg": 60.0, "aspect": 1.333}
"""The pinhole camera of every recording: ``position`` and ``target`` (m), vertical ``fov_deg``
(degrees), ``aspect`` (width / height)."""


@dataclass(frozen=True)
class Body:
    """A dynamic or static body of a recording: ``kind`` is ``box`` (``size`` full extents),
    ``sphere`` (``radius``), ``cylinder`` (``radius``, ``height``) or ``bin`` (open-top box of
    five walls, ``size`` outer extents, ``wall`` thickness); ``position`` (m) of its centre."""

    id: str
    kind: str
    position: tuple[float, float, float]
    size: tuple[float, float, float] | None = None
    radius: float | None = None
    height: float | None = None
    wall: float = 0.01
    mass: float = 0.1
    static: bool = False
    friction: float = 0.6
    rolling: float = 0.0
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    flick_t: float = 0.0
    tracked: bool = True


@dataclass(frozen=True)
class HandScript:
    """The hand's path: ``waypoints`` ``[(t, (x, y, z)), ...]`` reached at smooth-step speed between
    them; ``grasp``/``release`` ``(t, object id)``; ``collide``: whether its sphere pushes objects."""

    start: tuple[float, float, float]
    waypoints: tuple[tuple[float, tuple[float, float, float]], ...]
    grasp: tuple[float, str] | None = None
    release: tuple[float, str] | None = None
    holding: str | None = None
    collide: bool = False
    radius: float = 0.04
    tracked_until: float = math.inf


@dataclass(frozen=True)
class Recording:
    """A recording's set-up: its bodies, the hand script (or None), duration (s) and tracker noise
    (``position_std`` m, ``orientation_std_deg``, ``height_bias`` m, ``hand_std`` m)."""

    name: str
    description: str
    bodies: tuple[Body, ...]
    duration: float
    hand: HandScript | None = None
    position_std: float = 0.003
    orientation_std_deg: float = 1.0
    height_bias: float = 0.006
    hand_std: float = 0.01


TABLE = Body("table", "box", (0.0, 0.0, TABLE_TOP - 0.025), size=(1.5, 1.0, 0.05), static=True, friction=0.8)

RECORDINGS: dict[str, Recording] = {
    "flicked_ball": Recording(
        "flicked_ball", "a ball flicked along the table, no hand, rolls behind a box and stops there",
        (TABLE,
         Body("box", "box", (-0.25, 0.21, TABLE_TOP + 0.11), size=(0.10, 0.30, 0.22), mass=1.5),
         Body("ball", "sphere", (0.35, -0.22, TABLE_TOP + 0.032), radius=0.032, mass=0.06, rolling=0.003,
              velocity=(-1.05, 0.387, 0.0), flick_t=0.5)),
        duration=3.2),
    "ball_over_bin": Recording(
        "ball_over_bin", "a ball let go over an open bin from a hand that stays still and in view",
        (TABLE,
         Body("bin", "bin", (-0.2, 0.15, TABLE_TOP + 0.08), size=(0.22, 0.22, 0.16), mass=0.6),
         Body("ball", "sphere", (0.25, -0.2, TABLE_TOP + 0.03), radius=0.03, mass=0.05, rolling=0.002)),
        duration=3.2,
        hand=HandScript(start=(0.3, -0.35, 0.95),
                        waypoints=((0.5, (0.25, -0.2, TABLE_TOP + 0.07)), (1.1, (-0.2, 0.15, TABLE_TOP + 0.3)),
                                   (1.4, (-0.2, 0.15, TABLE_TOP + 0.21))),
                        grasp=(0.5, "ball"), release=(1.5, "ball"))),
    "mug_over_edge": Recording(
        "mug_over_edge", "a mug carried past the table's far edge and let go from a hand that stays still "
        "and in view; it falls to the floor behind the table",
        (TABLE,
         Body("mug", "cylinder", (0.0, 0.2, TABLE_TOP + 0.05), radius=0.042, height=0.10, mass=0.25)),
        duration=3.2,
        hand=HandScript(start=(0.2, 0.45, 1.0),
                        waypoints=((0.5, (0.0, 0.2, TABLE_TOP + 0.1)), (1.4, (-0.86, 0.2, TABLE_TOP + 0.12))),
                        grasp=(0.5, "mug"), release=(1.6, "mug"))),
    "box_shoved": Recording(
        "box_shoved", "a palm shoves a box along the table until it is hidden behind a screen, then "
        "leaves empty",
        (TABLE,
         Body("screen", "box", (-0.18, 0.3, TABLE_TOP + 0.15), size=(0.03, 0.4, 0.30), mass=2.0),
         Body("box", "box", (-0.36, -0.12, TABLE_TOP + 0.04), size=(0.12, 0.08, 0.08), mass=0.3, friction=0.5)),
        duration=3.6,
        hand=HandScript(start=(-0.2, -0.4, TABLE_TOP + 0.2),
                        waypoints=((0.6, (-0.36, -0.21, TABLE_TOP + 0.045)), (2.0, (-0.36, 0.24, TABLE_TOP + 0.045)),
                                   (2.6, (-0.36, 0.24, TABLE_TOP + 0.45)), (3.4, (0.2, -0.2, TABLE_TOP + 0.45))),
                        collide=True)),
}
