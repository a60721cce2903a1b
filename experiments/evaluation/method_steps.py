"""What the evaluated methods output, and the one method that is not the estimator.

:class:`StepEstimate` is what a method says at one reasoning step about the M objects of the scene
(scene order; positions in m, covariances in m^2, probabilities in [0, 1]); :class:`MethodRun` a
method's whole run (its steps, events, the wall-clock seconds of each step). :func:`step_from_belief`
reads a step from the estimator's :class:`~estimator.belief.Belief`; :class:`LastSeenBaseline` is the
``last-seen`` method of :mod:`experiments.evaluation.methods` (no physics, relations from the
bounding boxes of the last-seen poses).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.belief import Belief
from estimator.config import ReasonerConfig, reasoning_due
from estimator.observations import Frame
from estimator.relations import relation_list, relation_masks
from physics.scene import Scene
from physics.world import World

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
