"""What the person sees and reaches: per object, the probability that it is visible to the person
named by the scene (``person: {id, head, reach}``) and that it is within the person's reach, from
the particles (hidden objects included; the paper's use of the reasoner for objects the robot cannot
observe).

P(visible to the person) is the weight of the particles in which ray tests from the person's head
camera, in that particle's world (occlusion by everything it believes), see at least the
visibility threshold of the object's sample points; P(reachable) the weight of those in which the
object is within ``reach`` of one of the person's tracked hands (hands named ``"<id>/..."``, or all
tracked hands when none is), or of the head when no hand is tracked.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from physics.scene import PersonSpec


def person_probabilities(pool, person: PersonSpec, poses: np.ndarray, weights: np.ndarray, objects: np.ndarray,
                         place: np.ndarray, hands: dict, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """P(visible to the person) and P(reachable by the person), each ``(n,)`` for objects ``objects
    (n,)`` (NaN when there is no head camera / nothing to reach from), from particle ``poses (K, M,
    7)`` with normalised ``weights (K,)``; ``place (M,)``: the objects to set in the worlds (the
    known ones); ``hands``: tracked hand positions by name."""
    objects = np.asarray(objects, dtype=int)
    n = len(objects)
    p_vis = np.full(n, np.nan)
    if person.head is not None and n:
        p_vis = weights @ pool.look(poses, np.flatnonzero(place), objects, (person.head,), threshold)[0]  # (K, n)
    own = [np.asarray(p, float) for h, p in hands.items() if h.split("/")[0] == person.id]
    if not own:
        own = [np.asarray(p, float) for p in hands.values()]
    if not own and person.head is not None:
        own = [np.asarray(person.head.position, float)]
    p_reach = np.full(n, np.nan)
    if own and n:
        pts = np.array(own)  # (H, 3)
        d = np.linalg.norm(poses[:, objects, None, :3] - pts[None, None], axis=-1).min(axis=-1)  # (K, n)
        p_reach = weights @ (d <= person.reach)
    return p_vis, p_reach


def with_person(belief, pool, person: PersonSpec, poses: np.ndarray, weights: np.ndarray, objects: np.ndarray,
                known: np.ndarray, object_ids, hands: dict, threshold: float):
    """``belief`` (:class:`~estimator.belief.Belief`) with P(visible to) and P(reachable by)
    ``person`` for the objects ``objects (n,)`` (indices: the known dynamic ones), from the particles
    ``poses (K, M, 7)`` and ``weights (K,)`` (:func:`person_probabilities`: ray tests in ``pool``'s
    worlds; ``hands``: the tracked hands)."""
    p_vis, p_reach = person_probabilities(pool, person, poses, weights, objects, known, hands, threshold)
    out = dict(belief.objects)
    for j, m in enumerate(objects):
        oid = object_ids[m]
        if oid in out:
            out[oid] = replace(out[oid], person={
                "id": person.id, "p_visible": None if np.isnan(p_vis[j]) else round(float(p_vis[j]), 4),
                "p_reachable": None if np.isnan(p_reach[j]) else round(float(p_reach[j]), 4)})
    return replace(belief, objects=out)
