"""Ground-truth simulation of a scenario: a scripted human hand acting on a scene, a synthetic camera,
a faulty pose tracker, and the files an experiment runs on.

The ground truth runs in its own pybullet world (a :class:`physics.world.World` built from the
scenario's scene, plus a hand and an optional torso), never in the estimator's. One run:

1. :func:`~experiments.simulation.variants.sample_variant` draws the seeded variant of a :class:`~experiments.scenarios.Scenario`
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

from physics.errors import InputError
from physics.scene import Scene
from physics.world import PhysicsSettings

from experiments.simulation.files import FORMAT_VERSION, SimulationResult, _r, _round_tree, write_outputs
from experiments.simulation.ground_truth import HAND_ID, GroundTruth  # noqa: F401  (HAND_ID re-exported)
from experiments.simulation.variants import Variant, sample_variant
from experiments.scenarios import Scenario, load_scenario


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
                    settings: PhysicsSettings | None = None) -> Iterator[tuple[SimulationResult, GroundTruth]]:
    """Run ``scenario`` as :func:`simulate` does and keep its ground-truth world open while in the
    ``with`` block: yields ``(result, truth)``, ``truth`` being the :class:`GroundTruth` in its final
    state (hand and torso included), e.g. to ask what another camera would see at the end."""
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if duration is not None and not (duration > 0 and math.isfinite(duration)):
        raise InputError(f"duration must be > 0, got {duration}", field="duration")
    length = scenario.duration if duration is None else float(duration)
    variant = sample_variant(scenario, seed)
    perception_rng = np.random.default_rng([int(seed), 1])
    with GroundTruth(variant, settings) as gt:
        result = gt.run(length, perception_rng)
        _fill_result(result, scenario, seed, variant, gt, length)
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
             settings: PhysicsSettings | None = None) -> SimulationResult:
    """Run ``scenario`` (object or name/path) for ``seed``; ``duration`` (s) overrides the file's."""
    with open_simulation(scenario, seed, duration, settings) as (result, _truth):
        return result


def run_scenario(scenario: Scenario | str, seed: int, out_dir: str | os.PathLike,
                 duration: float | None = None) -> SimulationResult:
    """:func:`simulate` then :func:`write_outputs`."""
    result = simulate(scenario, seed, duration)
    write_outputs(result, out_dir)
    return result
