"""Ground-truth simulation of a scenario: a scripted human hand acting on a scene, a synthetic camera,
a faulty pose tracker, and the files an experiment runs on.

The ground truth runs in its own pybullet world (a :class:`physics.world.World` built from the
scenario's scene, plus a hand and an optional torso), never in the estimator's. One run:

1. :func:`~experiments.simulation.variants.sample_variant` draws the seeded variant of a :class:`~experiments.scenarios.specs.Scenario`
   (geometry, masses, frictions, timing) with ``numpy.random.default_rng(seed)``;
2. :class:`~experiments.simulation.ground_truth.GroundTruth` builds the world, lets it settle for ``scenario.settle`` seconds (the settled
   poses are the true initial poses), then steps it at 240 Hz while the hand follows its script;
3. at every camera frame (``perception.rate_hz``) it records the truth (poses, visibility, held
   objects, relations, events) and, through :class:`~experiments.simulation.camera.SyntheticCamera` and
   :class:`~experiments.simulation.perception.PerceptionModel`, what the tracker reports;
4. :func:`~experiments.simulation.files.write_outputs` writes ``scene.yaml``, ``observations.jsonl``, ``truth.jsonl`` and
   ``meta.json``; the same scenario and seed give byte-identical files.

The hand is a dynamic sphere pulled along its script by a fixed constraint to the world
(``changeConstraint`` moves the constraint's target every step, with a bounded force), so it pushes
objects physically when it collides (``collide: true``) and passes through them otherwise. A grasp is
a fixed constraint between the hand and the object at their relative pose of the moment; a release
removes it. The hand never collides with an object it holds.

Truth events (the estimator uses the same semantics):

* ``Pick``: the hand grasps an object (at the grasp time);
* ``Place``: the hand lets go of an object that rests on a support: it touches a body other than the
  hand, or the bounding-box relations (:mod:`estimator.relations`, 1.5 cm tolerance) put it on top of
  or inside another object or on the floor;
* ``Release``: the hand lets go of an object in the air (it falls, is dropped, is thrown);
* ``Push``: the hand, pushing (``collide``), moves an object it does not grasp along its support,
  never lifting it (:mod:`experiments.simulation.pushes`; at the time it started moving).

Objects moved only by other objects (a cup shoved off the table by a pushed box) and contents
carried inside a container the hand holds or pushes (the ball of a box being poured) get no event.
Events are listed in time order, each in the first truth frame at or after its time.
"""
from __future__ import annotations

import contextlib
import math
import os
from dataclasses import replace
from typing import Iterator

import numpy as np

from experiments.scenarios import load_scenario
from experiments.scenarios.specs import Scenario
from experiments.simulation.files import FORMAT_VERSION, SimulationResult, _r, _round_tree, write_outputs
from experiments.simulation.ground_truth import HAND_ID, GroundTruth  # noqa: F401  (HAND_ID re-exported)
from experiments.simulation.variants import Variant, sample_variant
from physics.errors import InputError
from physics.scene import Scene
from physics.world import PhysicsSettings

ENGINES = ("bullet", "mujoco")
"""Physics engines a ground truth can be simulated with: ``bullet`` (pybullet, the estimator's own
engine, :class:`~experiments.simulation.ground_truth.GroundTruth`) and ``mujoco`` (MuJoCo's soft
contacts, :class:`~experiments.simulation.mujoco_truth.MujocoGroundTruth`)."""

SCALED_PARAMETERS = ("friction", "rolling_friction", "restitution")
"""The dynamic objects' parameters :func:`scale_parameters` multiplies."""
DEFAULT_FRICTION = 0.5
"""Friction of an object whose scene states none (Bullet's default), before it is scaled."""
MAX_RESTITUTION = 0.95
"""A scaled restitution is capped here."""


def scale_parameters(variant: Variant, scale: float) -> Variant:
    """``variant`` with every dynamic object's friction, rolling friction and restitution
    (:data:`SCALED_PARAMETERS`, the values it has after the seed's draw) multiplied by ``scale``: the
    truth's parameters off the nominal ones the estimator's scene states. An unstated friction is
    :data:`DEFAULT_FRICTION` scaled; an unstated rolling friction or restitution stays unstated (0
    scaled); restitution is capped at :data:`MAX_RESTITUTION`. Static objects keep theirs (under
    Bullet's product rule a contact with one is then scaled by ``scale``)."""
    if not (scale > 0 and math.isfinite(scale)):
        raise InputError(f"must be a finite number > 0, got {scale}", field="param_scale")
    if scale == 1.0:
        return variant
    objects = []
    for spec in variant.scene.objects:
        if spec.static:
            objects.append(spec)
            continue
        friction = DEFAULT_FRICTION if spec.friction is None else spec.friction
        kw = {"friction": _r(friction * scale)}
        if spec.rolling_friction is not None:
            kw["rolling_friction"] = _r(spec.rolling_friction * scale)
        if spec.restitution is not None:
            kw["restitution"] = _r(min(spec.restitution * scale, MAX_RESTITUTION))
        objects.append(replace(spec, **kw))
    return replace(variant, scene=variant.scene.with_objects(objects))


def truth_class(engine: str):
    """The ground-truth class of ``engine`` (one of :data:`ENGINES`)."""
    if engine == "bullet":
        return GroundTruth
    if engine == "mujoco":
        from experiments.simulation.mujoco_truth import MujocoGroundTruth
        return MujocoGroundTruth
    raise InputError(f"unknown engine {engine!r} (one of {', '.join(ENGINES)})", field="engine")


# --------------------------------------------------------------------------------------------------
# the run


def estimator_scene(variant: Variant, initial_poses: np.ndarray) -> Scene:
    """The scene handed to the estimator: the true geometry at the true settled initial poses, with
    the scenario's *nominal* masses, frictions and restitution (the estimator does not know the
    sampled ones; they are in meta.json)."""
    nominal = {o.id: o for o in variant.scenario.scene.objects}
    objects = []
    for i, spec in enumerate(variant.scene.objects):
        nom = nominal[spec.id]
        pos = tuple(_r(v) for v in initial_poses[i, :3])
        q = np.asarray(initial_poses[i, 3:], dtype=float)
        q = q / np.linalg.norm(q)
        if q[3] < 0:
            q = -q
        objects.append(replace(spec, position=spec.position if spec.static else pos,
                               orientation=spec.orientation if spec.static else tuple(_r(v) for v in q),
                               mass=nom.mass, friction=nom.friction, rolling_friction=nom.rolling_friction,
                               spinning_friction=nom.spinning_friction, restitution=nom.restitution))
    return replace(variant.scene.with_objects(objects), source=None)


@contextlib.contextmanager
def open_simulation(scenario: Scenario | str, seed: int = 0, duration: float | None = None,
                    settings: PhysicsSettings | None = None, *, engine: str = "bullet",
                    param_scale: float = 1.0) -> Iterator[tuple[SimulationResult, GroundTruth]]:
    """Run ``scenario`` as :func:`simulate` does and keep its ground-truth world open while in the
    ``with`` block: yields ``(result, truth)``, ``truth`` being the :class:`GroundTruth` in its final
    state (hand and torso included), e.g. to ask what another camera would see at the end."""
    cls = truth_class(engine)
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if duration is not None and not (duration > 0 and math.isfinite(duration)):
        raise InputError(f"duration must be > 0, got {duration}", field="duration")
    length = scenario.duration if duration is None else float(duration)
    variant = scale_parameters(sample_variant(scenario, seed), param_scale)
    perception_rng = np.random.default_rng([int(seed), 1])
    with cls(variant, settings) as gt:
        result = gt.run(length, perception_rng)
        _fill_result(result, scenario, seed, variant, gt, length)
        if engine != "bullet":  # recorded only off the defaults: Bullet files stay what they were
            result.meta["engine"] = engine
        if param_scale != 1.0:
            result.meta["param_scale"] = _r(param_scale)
        yield result, gt


def _fill_result(result: SimulationResult, scenario: Scenario, seed: int, variant: Variant, gt: GroundTruth,
                 length: float) -> None:
    """Fill ``result.scene`` (the estimator's scene) and ``result.meta`` (meta.json)."""
    result.scene = estimator_scene(variant, result.initial_poses)
    result.meta = {
        "format_version": FORMAT_VERSION,
        "scenario": scenario.name,
        "description": scenario.description,
        "source": scenario.name if scenario.builtin else scenario.source,
        "seed": int(seed),
        "duration": _r(length),
        "time_step": _r(gt.dt),
        "frames": len(result.truth),
        "observation_frames": len(result.observations),
        "perception": scenario.perception.to_dict(),
        "height_offsets": {oid: _r(v) for oid, v in zip(variant.scene.object_ids, result.height_offsets)},
        "sampled": _round_tree(variant.sampled),
        "true_dynamics": {o.id: {k: (None if getattr(o, k) is None else _r(getattr(o, k)))
                                 for k in ("mass", "friction", "rolling_friction", "spinning_friction",
                                           "restitution")} for o in variant.scene.objects},
        "events": result.events,
        "hands_tracked": scenario.perception.hands_tracked,
        "warnings": result.warnings,
        "files": ["scene.yaml", "observations.jsonl", "truth.jsonl", "meta.json"],
    }


def simulate(scenario: Scenario | str, seed: int = 0, duration: float | None = None,
             settings: PhysicsSettings | None = None, *, engine: str = "bullet",
             param_scale: float = 1.0) -> SimulationResult:
    """Run ``scenario`` (object or name/path) for ``seed``; ``duration`` (s) overrides the file's.
    ``engine`` (:data:`ENGINES`) simulates the truth; ``param_scale`` multiplies the truth's frictions
    and restitution (:func:`scale_parameters`). The estimator's scene is the same for every engine and
    scale: nothing in the files but meta.json says which truth made them."""
    with open_simulation(scenario, seed, duration, settings, engine=engine, param_scale=param_scale) as (result, _t):
        return result


def run_scenario(scenario: Scenario | str, seed: int, out_dir: str | os.PathLike,
                 duration: float | None = None, *, engine: str = "bullet",
                 param_scale: float = 1.0) -> SimulationResult:
    """:func:`simulate` then :func:`write_outputs`."""
    result = simulate(scenario, seed, duration, engine=engine, param_scale=param_scale)
    write_outputs(result, out_dir)
    return result
