"""Scenario files: a scene, a scripted human hand, perception faults and randomisation ranges.

A scenario is one small YAML file. The built-in ones live in this folder (``*.yaml``); a user's own
file is accepted by path. :func:`list_scenarios` names the built-in ones and :func:`load_scenario`
reads and validates one (by name or path) into a frozen :class:`Scenario`. Every problem is reported
as a :class:`~physics.errors.SceneError` (an :class:`~physics.errors.InputError`) naming the file, the
line and the field. The records are in :mod:`experiments.scenarios.specs`, the validation in
:mod:`experiments.scenarios.parsing`; this package re-exports both.

Format (units: metres, kilograms, seconds, degrees)::

    name: my_scenario              # default: the file name
    description: one line
    duration: 4.0                  # seconds of recorded simulation
    settle: 0.3                    # seconds simulated before t = 0 (then on until objects rest)
    scene: {...}                   # a scene in the scene-file format (objects, camera, floor)
    hand:                          # optional: the scripted human hand
      radius: 0.035                # a sphere (m)
      start: [-0.9, -0.3, 1.0]     # position at t = 0
      rpy: [0, 0, 0]               # orientation at t = 0 (degrees, roll / pitch / yaw)
      holding: ball                # optional: grasped from the start (no Pick event)
      collide: false               # whether the hand pushes objects (initial state)
      script:                      # timed waypoints, t non-decreasing
        - {t: 1.0, to: {object: cup, offset: [0, 0, 0.09]}, grasp: cup}
        - {t: 2.0, by: [0, 0, 0.1], rpy: [0, -90, 0]}
        - {t: 2.2, release: cup, collide: true}
    torso: {size: [0.2, 0.4, 0.7], position: [-1.0, 0, 1.1]}   # optional occluder (no collisions)
    perception: {...}              # fields of experiments.simulation.perception.PerceptionConfig
    randomize:
      timing: {scale: [0.9, 1.1], delay: [0.0, 0.2]}
      objects:
        cup: {position: 0.02, yaw: [-20, 20], size: [0.95, 1.05], mass: [0.8, 1.2],
              friction: [0.4, 0.7]}

A waypoint's motion (``to``: absolute ``[x, y, z]`` or ``{object, offset}``; or ``by``: a displacement
from the previous waypoint) ends at its ``t``; it starts at the previous waypoint's time, from where
the hand was, along a smooth (zero end velocity) straight line. An object-relative target is resolved
from the object's true position when the motion starts. Its actions (``grasp``, ``release``,
``collide``) happen when the hand arrives. Randomised ``position`` ranges are added to x, y, z (a
number r means +-r on x and y); ``yaw`` (degrees) is added about z; ``size`` and ``mass`` are
factors (a resized object keeps its bottom where it was); frictions and restitution are drawn
absolute. ``timing.scale`` scales each segment's duration independently; ``timing.delay`` shifts the
whole script.
"""
from __future__ import annotations

import os
from pathlib import Path

from experiments.scenarios.parsing import scenario_from_dict
from experiments.scenarios.specs import (
    HandSpec,
    HandTarget,
    ObjectRandomization,
    Randomization,
    Scenario,
    TorsoSpec,
    Waypoint,
)
from physics.errors import InputError
from physics.fields import read_yaml_with_lines

SCENARIO_DIR = Path(__file__).resolve().parent


# --------------------------------------------------------------------------------------------------
# registry


def list_scenarios() -> list[str]:
    """Names of the built-in scenarios (the ``*.yaml`` files of this package), sorted."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def scenario_path(name_or_path: str | os.PathLike) -> tuple[Path, bool]:
    """The file of a scenario given by built-in name or by path; ``(path, builtin)``."""
    text = str(name_or_path)
    builtin = SCENARIO_DIR / f"{text}.yaml"
    if os.sep not in text and "/" not in text and builtin.is_file():
        return builtin, True
    p = Path(text)
    if p.is_file():
        return p, False
    if p.suffix in (".yaml", ".yml", ".json") or os.sep in text or "/" in text:
        raise InputError("scenario file not found", path=text)
    raise InputError(f"unknown scenario {text!r}; available: {', '.join(list_scenarios())} "
                     "(or give the path of a scenario file)")


def load_scenario(name_or_path: str | os.PathLike) -> Scenario:
    """Read and validate a scenario by built-in name or by path. Raises :class:`InputError`."""
    path, builtin = scenario_path(name_or_path)
    data, lines = read_yaml_with_lines(path, "scenario file")
    return scenario_from_dict(data, path=str(path), lines=lines, builtin=builtin)


def describe(name_or_path: str) -> str:
    """One-line description of a scenario (its ``description`` field)."""
    return load_scenario(name_or_path).description


__all__ = ["HandSpec", "HandTarget", "ObjectRandomization", "Randomization", "Scenario", "TorsoSpec",
           "Waypoint", "describe", "list_scenarios", "load_scenario", "scenario_from_dict",
           "scenario_path", "SCENARIO_DIR"]


def resolve_scenarios(names: list[str]) -> list[str]:
    """The scenarios ``names`` ask for, in order, without repeats; ``all`` stands for every built-in
    one. Raises :class:`~physics.errors.InputError` for a name that is neither a built-in scenario nor a scenario file,
    naming it and listing the built-in ones."""
    out: list[str] = []
    for name in names:
        for n in (list_scenarios() if name == "all" else [name]):
            if n not in out:
                out.append(n)
    for n in out:
        load_scenario(n)  # all checked before anything runs
    return out
