"""The Kalman tracker's evaluation methods (``tracker``, ``tracker-feedback``, ``particles-on-tracker``
of :mod:`experiments.evaluation.methods`): :class:`TrackerMethod` steps the
:class:`~estimator.applications.tracker.PhysicsAwareTracker`, alone or beside the particle estimator,
on the estimator's reasoning schedule, and :func:`_run_tracker_method` runs it over a stream into a
:class:`~experiments.evaluation.method_steps.MethodRun` (with what the tracker's gate did with each
detection).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from estimator.applications.tracker import PhysicsAwareTracker, TrackerConfig
from estimator.belief import Belief
from estimator.config import EstimatorConfig, ReasonerConfig, reasoning_due
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from experiments.evaluation.method_steps import MethodRun, StepEstimate, step_from_belief
from physics.scene import Scene


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
