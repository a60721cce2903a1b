"""Seeded variants of a scenario: the geometry, masses, frictions and timing one seed draws."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from experiments.scenarios.specs import Scenario, Waypoint
from experiments.simulation.files import DECIMALS, _r
from physics.bodies import DEFAULT_PRIMITIVE_MASS
from physics.scene import Scene
from physics.transforms import quat_from_axis_angle, quat_multiply, quat_normalize


@dataclass(frozen=True)
class Variant:
    """One seeded instance of a scenario: the true scene (before settling), the retimed hand script,
    and the sampled values (``sampled``, plain JSON) for meta.json."""

    scenario: Scenario
    seed: int
    scene: Scene
    script: tuple[Waypoint, ...]
    sampled: dict


def _resize(spec, factor: float):
    """``spec`` scaled by ``factor`` about its centre, moved so that its bottom stays put (primitives
    are assumed upright; URDFs scale about their frame)."""
    kw: dict[str, Any] = {}
    half_before = half_after = 0.0
    factor = round(factor, DECIMALS)
    if spec.shape in ("box", "container"):
        kw["size"] = tuple(_r(v * factor) for v in spec.size)
        half_before, half_after = spec.size[2] / 2, kw["size"][2] / 2
    elif spec.shape == "sphere":
        kw["radius"] = _r(spec.radius * factor)
        half_before, half_after = spec.radius, kw["radius"]
    elif spec.shape == "cylinder":
        kw["radius"], kw["height"] = _r(spec.radius * factor), _r(spec.height * factor)
        half_before, half_after = spec.height / 2, kw["height"] / 2
    else:
        kw["scale"] = _r(spec.scale * factor)
    if spec.position is not None:
        p = list(spec.position)
        p[2] += half_after - half_before
        kw["position"] = tuple(p)
    return replace(spec, **kw)


def sample_variant(scenario: Scenario, seed: int) -> Variant:
    """Draw the variant of ``scenario`` for ``seed`` (``numpy.random.default_rng(seed)``).

    Draws happen in a fixed order: objects in scene order, each in the order position (x, y, z), yaw,
    size, mass, friction, rolling_friction, spinning_friction, restitution; then one duration factor
    per waypoint and the script delay.
    """
    rng = np.random.default_rng(seed)
    rand = {r.id: r for r in scenario.randomize.objects}
    objects = list(scenario.scene.objects)
    sampled_objects: dict[str, Any] = {}
    for i, spec in enumerate(objects):
        r = rand.get(spec.id)
        if r is None:
            continue
        rec: dict[str, Any] = {}
        if r.position is not None:
            d = [float(rng.uniform(lo, hi)) for lo, hi in r.position]
            if spec.position is not None:
                spec = replace(spec, position=tuple(float(a + b) for a, b in zip(spec.position, d)))
            rec["position_offset"] = d
        if r.yaw_deg is not None:
            yaw = float(rng.uniform(*r.yaw_deg))
            q = quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(yaw)),
                              np.asarray(spec.orientation))
            spec = replace(spec, orientation=tuple(float(v) for v in quat_normalize(q)))
            rec["yaw_deg"] = yaw
        if r.size is not None:
            factor = float(rng.uniform(*r.size))
            spec = _resize(spec, factor)
            rec["size_factor"] = factor
        physics = _draw_physics(r, spec.mass, rng)
        spec = replace(spec, **physics)
        rec.update(physics)
        objects[i] = spec
        sampled_objects[spec.id] = rec
    script: tuple[Waypoint, ...] = ()
    timing: dict[str, Any] = {}
    if scenario.hand is not None:
        wps = scenario.hand.script
        lo, hi = scenario.randomize.time_scale
        scales = [float(rng.uniform(lo, hi)) if hi > lo else lo for _ in wps]
        dlo, dhi = scenario.randomize.delay
        delay = float(rng.uniform(dlo, dhi)) if dhi > dlo else dlo
        times, t_prev, t_new = [], 0.0, delay
        for wp, s in zip(wps, scales):
            t_new += (wp.t - t_prev) * s
            t_prev = wp.t
            times.append(t_new)
        limit = scenario.duration - 0.1
        if times and times[-1] > limit:  # keep the whole script inside the run
            k = max(limit - delay, 0.0) / max(times[-1] - delay, 1e-9)
            times = [delay + (t - delay) * k for t in times]
        script = tuple(replace(wp, t=float(t)) for wp, t in zip(wps, times))
        timing = {"delay": delay, "segment_scale": scales}
    sampled = {"objects": sampled_objects, "timing": timing}
    return Variant(scenario=scenario, seed=int(seed), scene=scenario.scene.with_objects(objects),
                   script=script, sampled=sampled)


TWIN_PARAMETERS = ("mass", "friction", "rolling_friction", "spinning_friction", "restitution")
"""The physical parameters a twin perturbs (those the variant sets)."""


def twin_variant(variant: Variant, rng: np.random.Generator, position_std: float,
                 param_scale: float) -> Variant:
    """A twin of ``variant``: the same scene and hand script, with every dynamic object's horizontal
    starting position moved by Gaussian noise of ``position_std`` (m, per axis) and each of its
    physical parameters the variant sets (:data:`TWIN_PARAMETERS`; a URDF's own mass is left alone)
    multiplied by a uniform factor in ``[1 - param_scale, 1 + param_scale]``. Draws, from ``rng``, in
    scene order: x, y offsets, then the factors in :data:`TWIN_PARAMETERS` order. Static objects and
    the hand do not change.

    Where twins a millimetre apart end far apart, the scene is chaotic: no estimator can say where
    its objects end (:mod:`experiments.evaluation.predictability`, ``at="start"``)."""
    if not (position_std >= 0 and math.isfinite(position_std)):
        raise ValueError(f"position_std must be finite and >= 0, got {position_std}")
    if not (0 <= param_scale < 1):
        raise ValueError(f"param_scale must be in [0, 1), got {param_scale}")
    objects = []
    for spec in variant.scene.objects:
        if spec.static:
            objects.append(spec)
            continue
        kw: dict[str, Any] = {}
        dx, dy = (float(v) for v in rng.normal(0.0, 1.0, 2) * position_std)
        if spec.position is not None:
            kw["position"] = (spec.position[0] + dx, spec.position[1] + dy, spec.position[2])
        for key in TWIN_PARAMETERS:
            factor = float(rng.uniform(1.0 - param_scale, 1.0 + param_scale))
            value = getattr(spec, key)
            if value is not None:
                kw[key] = value * factor
        objects.append(replace(spec, **kw))
    return replace(variant, scene=variant.scene.with_objects(objects))


def draw_parameters(variant: Variant, rng: np.random.Generator) -> dict[str, dict[str, float]]:
    """The physical parameters ``variant``'s scenario randomises, drawn again from ``rng``: per
    object id with a ``randomize`` entry (dynamic objects, in scene order), its ``mass`` (kg: the
    scenario's nominal mass times a factor drawn in the entry's range) and each of ``friction``,
    ``rolling_friction``, ``spinning_friction`` and ``restitution`` the entry gives a range for,
    uniformly in it, in that order.

    The estimator is told the scenario's nominal values, not the ones a seed drew
    (:func:`~experiments.simulation.simulator.estimator_scene`): a twin that differs from the truth
    by what the robot could not know takes these from an object's last sighting on
    (:mod:`experiments.evaluation.predictability`)."""
    rand = {r.id: r for r in variant.scenario.randomize.objects}
    nominal = {o.id: o for o in variant.scenario.scene.objects}
    return {spec.id: _draw_physics(rand[spec.id], nominal[spec.id].mass, rng)
            for spec in variant.scene.objects if spec.id in rand and not spec.static}


def _draw_physics(r, mass: float | None, rng: np.random.Generator) -> dict[str, float]:
    """The physical parameters a ``randomize`` entry ``r`` draws, in this order: ``mass`` (kg, ``mass``
    or the primitive default times a factor in the entry's range), then each of friction, rolling
    and spinning friction and restitution it gives a range for, uniformly in it."""
    out: dict[str, float] = {}
    if r.mass is not None:
        factor = float(rng.uniform(*r.mass))
        out["mass"] = (mass if mass is not None else DEFAULT_PRIMITIVE_MASS) * factor
    for key in ("friction", "rolling_friction", "spinning_friction", "restitution"):
        lo_hi = getattr(r, key)
        if lo_hi is not None:
            out[key] = float(rng.uniform(*lo_hi))
    return out
