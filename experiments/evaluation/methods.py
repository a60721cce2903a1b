"""The methods an evaluation compares, by name, and one common way to run them on a stream.

=========================  ===================================================================
name                       what it is
=========================  ===================================================================
``last-seen``              no physics: an unperceived object stays where it was last seen
                           (a baseline, implemented here; not estimator logic)
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
:class:`MethodRun`: one :class:`StepEstimate` per reasoning step (every method reasons on the same
schedule, one step per ``ReasonerConfig.horizon`` of stream time, so that all methods are scored at
the same instants), the events of the run, and the wall-clock time of every step.
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from actions.modes import ModePriors
from estimator.applications.tracker import PhysicsAwareTracker, TrackerConfig
from estimator.belief import Belief
from estimator.config import (
    AdaptiveConfig,
    EstimatorConfig,
    NoiseConfig,
    ReasonerConfig,
    config_from_dict,
    reasoning_due,
    with_adaptive_count,
)
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from estimator.relations import relation_list, relation_masks
from physics.scene import Scene
from physics.world import World

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
    Kalman tracker takes part (``"alone"``, ``"feedback"``, ``"input"``; see :class:`TrackerMethod`)."""

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
# what a method outputs


@dataclass
class StepEstimate:
    """What a method says at one reasoning step, for the M objects of the scene (scene order).

    * ``t`` (s); ``positions (M, 3)`` m, NaN for objects the method does not know yet;
    * ``covariances (M, 3, 3)`` m^2 (zeros for point estimates);
    * ``p_plausible (M,)``, ``p_held (M,)`` probabilities;
    * ``top (M,)`` the most probable ``(relation, support)`` of each object (``relation`` in isIn,
      isOnTop, held, none; ``support`` an object id, ``"floor"`` or ``None``);
    * ``relations``: ``{(subject, predicate, object): p}`` for every listed relation;
    * ``particles (K, M, 3)`` and ``weights (K,)``: the particle cloud, kept only when asked for;
    * ``dof (M,)``: degrees of freedom of each position's Student-t (``inf``: Gaussian; ``None``:
      every position Gaussian).
    """

    t: float
    positions: np.ndarray
    covariances: np.ndarray
    p_plausible: np.ndarray
    p_held: np.ndarray
    top: list[tuple[str, str | None]]
    relations: dict[tuple[str, str, str], float]
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None
    dof: np.ndarray | None = None


@dataclass
class MethodRun:
    """A method's whole run: its steps, its events (``[{"t", "action", "subject", "p"}]``, the
    timeline's for the estimator, none for last-seen), the wall-clock duration (s) of every step, and
    the number of particle worlds. ``gate_actions``: for the Kalman tracker's methods, what the
    tracker did with each detection, by ``(frame index, object id)`` (``"accepted"``, ``"rejected"``,
    ``"initialised"``, ``"reinitialised"``); ``None`` for the others."""

    steps: list[StepEstimate]
    events: list[dict]
    step_seconds: list[float] = field(default_factory=list)
    particles: int = 0
    gate_actions: dict[tuple[int, str], str] | None = None
    mean_particles: float | None = None


def step_from_belief(belief: Belief, object_ids, keep_particles: bool = False) -> StepEstimate:
    """A :class:`StepEstimate` from an estimator :class:`~estimator.belief.Belief`."""
    m = len(object_ids)
    pos = np.full((m, 3), np.nan)
    cov = np.zeros((m, 3, 3))
    p_pl = np.ones(m)
    p_held = np.zeros(m)
    dof = np.full(m, np.inf)
    top: list[tuple[str, str | None]] = []
    for i, oid in enumerate(object_ids):
        ob = belief.objects.get(oid)
        if ob is None:
            top.append(("none", None))
            continue
        pos[i] = ob.position
        cov[i] = ob.position_cov
        dof[i] = ob.position_dof
        p_pl[i] = ob.p_plausible
        p_held[i] = ob.p_held
        top.append((ob.hypotheses[0].relation, ob.hypotheses[0].support) if ob.hypotheses else ("none", None))
    rel = {(r["subject"], r["predicate"], r["object"]): float(r["p"]) for r in belief.relations}
    parts = weights = None
    if keep_particles and belief.particles is not None:
        parts = np.asarray(belief.particles)[..., :3].copy()
        weights = np.asarray(belief.weights).copy()
    return StepEstimate(float(belief.t), pos, cov, p_pl, p_held, top, rel, parts, weights, dof)


# --------------------------------------------------------------------------------------------------
# the last-seen baseline


def top_from_relations(relations: dict[tuple[str, str, str], float], subject: str,
                       held: bool = False) -> tuple[str, str | None]:
    """The support of ``subject`` from a relation dict: isIn X, else isOnTop X, else held, else none
    (the first listed at the winning level, relations with p > 0.5 only)."""
    for predicate in ("isIn", "isOnTop"):
        for (s, p, o), prob in relations.items():
            if s == subject and p == predicate and prob > 0.5:
                return predicate, o
    return ("held", None) if held else ("none", None)


class LastSeenBaseline:
    """No physics: every object is where it was last perceived (its scene pose until then), with a
    zero covariance, plausible and never held. Relations come from the bounding boxes of those poses
    (the same tests as the ground truth), which is what a perception-only system would report.

    Reasons on the estimator's schedule: at the first frame, then whenever ``horizon`` seconds of
    stream time have passed since the last step.
    """

    def __init__(self, scene: Scene, horizon: float = ReasonerConfig().horizon):
        self.scene = scene
        self.ids = scene.object_ids
        self.horizon = horizon
        self.static = np.array([o.static for o in scene.objects], dtype=bool)
        self.known = np.array([o.position is not None for o in scene.objects], dtype=bool)
        self.world = World(scene)
        self.poses = self.world.get_poses()
        self.t_step: float | None = None
        self.previous = None

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> "LastSeenBaseline":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, frame: Frame) -> StepEstimate | None:
        for oid, det in frame.objects.items():
            i = self.scene.index(oid)
            if self.static[i]:
                continue
            self.poses[i, :3] = det.position
            if det.orientation is not None:
                self.poses[i, 3:] = det.orientation
            self.known[i] = True
        if not reasoning_due(self.t_step, frame.t, self.horizon):
            return None
        self.t_step = frame.t
        dyn = np.flatnonzero(~self.static)
        self.world.set_poses(self.poses[dyn], dyn)
        aabbs = self.world.aabbs()
        self.previous = relation_masks(aabbs, self.known, static=self.static, floor=self.scene.floor,
                                       previous=self.previous, hollow=self.scene.hollow)
        rels = {(r["subject"], r["predicate"], r["object"]): float(r["p"])
                for r in relation_list(self.previous[0], self.previous[1], self.ids)}
        m = len(self.ids)
        pos = np.where(self.known[:, None], self.poses[:, :3], np.nan)
        top = [top_from_relations(rels, oid) for oid in self.ids]
        return StepEstimate(frame.t, pos, np.zeros((m, 3, 3)), np.ones(m), np.zeros(m), top, rels)


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


# --------------------------------------------------------------------------------------------------
# the Kalman tracker's methods


class TrackerMethod:
    """The Kalman tracker (:class:`~estimator.applications.tracker.PhysicsAwareTracker`) as a method.

    ``mode`` ``"alone"``: the tracker without feedback, reasoning on the estimator's schedule (every
    ``horizon`` s); its positions and position covariances, no relations, never held.
    ``"feedback"``: the estimator runs beside it on the raw frames; at each of its steps its belief
    gives the tracker pseudo-measurements for the dynamic objects not detected; the step has the
    tracker's positions and covariances and the estimator's relations, P(held), P(plausible).
    ``"input"``: the estimator is fed the tracker's filtered poses (no feedback); the step is its belief.
    """

    def __init__(self, scene: Scene, mode: str, config: EstimatorConfig | None, rng: np.random.Generator,
                 tracker_config: TrackerConfig = TrackerConfig()):
        if mode not in ("alone", "feedback", "input") or (config is None) != (mode == "alone"):
            raise ValueError(f"tracker mode {mode!r} with estimator configuration {config!r}")
        self.mode, self.ids = mode, scene.object_ids
        dynamic = tuple(o.id for o in scene.objects if not o.static)
        self.tracker = PhysicsAwareTracker(
            dataclasses.replace(tracker_config, use_feedback=mode == "feedback", feed_estimator=mode == "input"),
            dynamic)
        self.estimator = None if config is None else SceneEstimator(scene, config, rng)
        self.horizon = (config.reasoner if config is not None else ReasonerConfig()).horizon
        self.t_step: float | None = None

    def close(self) -> None:
        if self.estimator is not None:
            self.estimator.close()

    def __enter__(self) -> "TrackerMethod":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, frame: Frame) -> tuple[StepEstimate, Belief | None] | None:
        """One frame; the step and the estimator's belief (``None`` when it has none) at a reasoning
        step. The tracker's :class:`~estimator.applications.tracker.Outcome` of the frame is :attr:`outcome`."""
        self.outcome = self.tracker.update(frame)
        if self.mode == "input":
            belief = self.estimator.update(self.tracker.to_frame(hands=frame.hands, detected_only=True))
            return None if belief is None else (step_from_belief(belief, self.ids), belief)
        if self.mode == "feedback":
            belief = self.estimator.update(frame)
            if belief is None:
                return None
            self.tracker.feedback(belief)
            return self._step(frame.t, belief), belief
        if not reasoning_due(self.t_step, frame.t, self.horizon):
            return None
        self.t_step = frame.t
        return self._step(frame.t, None), None

    def _step(self, t: float, belief: Belief | None) -> StepEstimate:
        m = len(self.ids)
        if belief is not None:
            step = step_from_belief(belief, self.ids)
        else:
            step = StepEstimate(t, np.full((m, 3), np.nan), np.zeros((m, 3, 3)), np.ones(m), np.zeros(m),
                                [("none", None)] * m, {})
        for i, oid in enumerate(self.ids):
            track = self.tracker.tracks.get(oid)
            step.positions[i] = np.nan if track is None else track.position
            step.covariances[i] = 0.0 if track is None else track.position_cov
        step.dof = None  # the tracker's positions are Gaussian
        return step


def _run_tracker_method(mode: str, scene: Scene, frames: list[Frame], cfg: EstimatorConfig | None,
                        rng: np.random.Generator, on_step) -> MethodRun:
    steps: list[StepEstimate] = []
    seconds: list[float] = []
    actions: dict[tuple[int, str], str] = {}
    with TrackerMethod(scene, mode, cfg, rng) as method:
        for i, frame in enumerate(frames):
            t0 = time.perf_counter()
            out = method.update(frame)
            actions.update({(i, oid): a for oid, a in method.outcome.action.items()})
            if out is None:
                continue
            seconds.append(time.perf_counter() - t0)
            steps.append(out[0])
            if on_step is not None:
                on_step(out[0], out[1])
        events = [] if method.estimator is None else method.estimator.timeline.to_json()["events"]
    return MethodRun(steps, events, seconds, 0 if cfg is None else cfg.particles, actions)
