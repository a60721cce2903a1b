"""The methods an evaluation compares, by name, and one common way to run them on a stream.

=========================  ===================================================================
name                       what it is
=========================  ===================================================================
``last-seen``              no physics: an unperceived object stays where it was last seen
                           (a baseline, :class:`~experiments.evaluation.method_steps.LastSeenBaseline`;
                           not estimator logic)
``paper``                  the paper's reasoner: one world, no noise (:meth:`EstimatorConfig.paper`)
``particles``              the particle estimator with the default noise and priors
``particles-no-params``    ablation: no perturbation of the physical parameters
``particles-no-held``      ablation: a held object that vanishes is always released (as the paper
                           does) and held objects do not follow the tracked hands
``particles-no-negative``  ablation: no negative evidence from the camera
``tracker``                a constant-velocity Kalman tracker alone
                           (:class:`~estimator.applications.tracker.PhysicsAwareTracker` without feedback): its
                           positions and covariances, no relations; a lost object is unknown (NaN)
                           once its track is dropped
``tracker-feedback``       the tracker kept alive by the particle estimator, which runs beside it
                           on the raw frames: positions and covariances are the tracker's,
                           relations, held and events the estimator's
``particles-on-tracker``   the particle estimator fed the tracker's filtered poses (no feedback)
=========================  ===================================================================

:func:`run_method` runs any of them on a scene and a list of perception frames and returns a
:class:`~experiments.evaluation.method_steps.MethodRun`: one
:class:`~experiments.evaluation.method_steps.StepEstimate` per reasoning step (every method reasons on
the same schedule, one step per ``ReasonerConfig.horizon`` of stream time, so that all methods are
scored at the same instants), the events of the run, and the wall-clock time of every step. The
tracker's methods run through :mod:`experiments.evaluation.tracker_method`.
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from actions.modes import ModePriors
from estimator.belief import Belief
from estimator.config import AdaptiveConfig, EstimatorConfig, NoiseConfig, config_from_dict, with_adaptive_count
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.evaluation.method_steps import LastSeenBaseline, MethodRun, StepEstimate, step_from_belief
from experiments.evaluation.tracker_method import _run_tracker_method
from physics.scene import Scene

# --------------------------------------------------------------------------------------------------
# the registry


def _particles_config(particles: int) -> EstimatorConfig:
    return EstimatorConfig(particles=particles, noise=NoiseConfig())


def _no_params(particles: int) -> EstimatorConfig:
    base = _particles_config(particles)
    noise = dataclasses.replace(base.noise, friction_range=None, rolling_friction_range=None,
                                spinning_friction_range=None, restitution_range=None,
                                mass_scale_range=None, param_jitter=0.0)
    return dataclasses.replace(base, noise=noise)


def _no_held(particles: int) -> EstimatorConfig:
    base = _particles_config(particles)
    return dataclasses.replace(base, priors=dataclasses.replace(ModePriors(), release_on_loss=1.0),
                               follow_hands=False)


def _no_negative(particles: int) -> EstimatorConfig:
    return dataclasses.replace(_particles_config(particles), negative_evidence=False)


@dataclass(frozen=True)
class MethodSpec:
    """A named method. ``config(K)`` builds its estimator configuration for K particles (``None``
    for the last-seen baseline and the tracker alone); ``uses_particles`` says whether the sweep's K
    applies (otherwise the method always runs with one world). ``tracker``: ``None``, or how the
    Kalman tracker takes part (``"alone"``, ``"feedback"``, ``"input"``; see
    :class:`~experiments.evaluation.tracker_method.TrackerMethod`)."""

    name: str
    description: str
    uses_particles: bool
    config: Callable[[int], EstimatorConfig] | None
    tracker: str | None = None


METHODS: dict[str, MethodSpec] = {m.name: m for m in [
    MethodSpec("last-seen", "no physics: an unperceived object stays where it was last seen", False, None),
    MethodSpec("paper", "the paper's reasoner: one world, no noise", False, lambda k: EstimatorConfig.paper()),
    MethodSpec("particles", "particle estimator, default noise and priors", True, _particles_config),
    MethodSpec("particles-no-params", "ablation: no physical-parameter perturbation", True, _no_params),
    MethodSpec("particles-no-held", "ablation: no held mode for vanished objects (always released)", True,
               _no_held),
    MethodSpec("particles-no-negative", "ablation: no negative evidence", True, _no_negative),
    MethodSpec("tracker", "constant-velocity Kalman tracker alone", False, None, "alone"),
    MethodSpec("tracker-feedback", "Kalman tracker kept alive by the particle estimator's belief", True,
               _particles_config, "feedback"),
    MethodSpec("particles-on-tracker", "particle estimator fed the Kalman tracker's filtered poses", True,
               _particles_config, "input"),
]}


def get_method(name: str) -> MethodSpec:
    """The :class:`MethodSpec` called ``name``; ``ValueError`` naming the known ones otherwise."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None


AUTO = 0
"""``particles`` of a sweep that asks for the adaptive particle count (``--particles auto``:
:class:`~estimator.config.AdaptiveConfig`, starting from its minimum)."""


def effective_particles(name: str, particles: int) -> int:
    """Number of worlds method ``name`` runs with when the sweep asks for ``particles`` (:data:`AUTO`
    for the particle methods asked for the adaptive count)."""
    spec = get_method(name)
    if spec.config is None:
        return 0
    return int(particles) if spec.uses_particles else spec.config(1).particles


def particles_label(particles: int) -> str:
    """``"auto"`` for :data:`AUTO`, else the number."""
    return "auto" if particles == AUTO else str(particles)


def method_label(name: str, particles: int) -> str:
    """How reports and figures name method ``name`` run with ``particles`` worlds: ``"particles (K=64)"``
    for the methods whose K the sweep sets, the bare name for the others."""
    return f"{name} (K={particles_label(particles)})" if get_method(name).uses_particles else name


def method_config(name: str, particles: int, config: str | None = None) -> EstimatorConfig | None:
    """Estimator configuration of method ``name`` with ``particles`` worlds (``None`` for
    last-seen), with the fields of ``config`` (configuration data as JSON, see
    :func:`estimator.config.config_from_dict`) on top. Every method runs its worlds in the trial's
    own process (``workers = 0``): trials are the unit of parallelism, and results never depend on
    the number of processes."""
    spec = get_method(name)
    if spec.config is None:
        return None
    k = effective_particles(name, particles)
    if k == AUTO and spec.uses_particles:
        cfg = with_adaptive_count(spec.config(AdaptiveConfig().min_particles))
    else:
        cfg = spec.config(k)
    if config is not None:
        cfg = config_from_dict(json.loads(config), start=cfg)
    return dataclasses.replace(cfg, workers=0)


# --------------------------------------------------------------------------------------------------
# running a method


def run_method(name: str, scene: Scene, frames: list[Frame], particles: int, rng: np.random.Generator,
               keep_particles: bool = False, on_step: Callable[[StepEstimate, Belief | None], None] | None = None,
               config: str | None = None) -> MethodRun:
    """Run method ``name`` on ``frames`` of ``scene``.

    Args:
        particles: K for the particle methods (ignored by last-seen and paper).
        rng: the only source of randomness of the run.
        keep_particles: keep the particle cloud of the *last* step (for plots).
        on_step: called with every step and the estimator's belief (``None`` for last-seen), e.g. to
            record it.
        config: configuration data (JSON) on top of the method's own (see :func:`method_config`).
    """
    cfg = method_config(name, particles, config)
    steps: list[StepEstimate] = []
    seconds: list[float] = []
    counts: list[int] = []  # K of every update
    ids = scene.object_ids
    last: Belief | None = None
    mode = get_method(name).tracker
    if mode is not None:
        return _run_tracker_method(mode, scene, frames, cfg, rng, on_step)
    if cfg is None:
        model, to_step = LastSeenBaseline(scene), (lambda step: step)
    else:
        model, to_step = SceneEstimator(scene, cfg, rng), (lambda belief: step_from_belief(belief, ids))
    with model:
        for frame in frames:
            t0 = time.perf_counter()
            out = model.update(frame)
            if out is None:
                continue
            seconds.append(time.perf_counter() - t0)
            steps.append(to_step(out))
            if cfg is not None:
                last = out
                counts.append(out.n_particles or cfg.particles)
            if on_step is not None:
                on_step(steps[-1], last)
        events = [] if cfg is None else model.timeline.to_json()["events"]
    if cfg is None:
        return MethodRun(steps, events, seconds, 0)
    if keep_particles and last is not None and steps:
        steps[-1] = step_from_belief(last, ids, keep_particles=True)
    return MethodRun(steps, events, seconds, cfg.particles,
                     mean_particles=float(np.mean(counts)) if counts else None)
