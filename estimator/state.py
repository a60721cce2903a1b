"""The particles: a structure of arrays, K particles by M objects."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from actions.events import N_ACTIONS
from actions.push import HOLD_FIELDS
from physics.transforms import carry_pose


@dataclass(frozen=True)
class ArraySpec:
    """A per-particle array declared by the state (:data:`ARRAYS`) or by a mechanism
    (:attr:`~estimator.model.mechanisms.base.Mechanism.arrays`): shape ``(K, M) + tail`` (an entry of
    ``tail`` may be ``"M"`` or ``"M+1"``), ``dtype`` and the value it starts with, ``fill``."""

    tail: tuple = ()
    dtype: type = float
    fill: float = 0.0

    def make(self, K: int, M: int) -> np.ndarray:
        """The array for K particles and M objects, filled."""
        tail = tuple(M if d == "M" else M + 1 if d == "M+1" else int(d) for d in self.tail)
        return np.full((K, M) + tail, self.fill, dtype=self.dtype)


ARRAYS = {
    "on_top": ArraySpec(("M+1",), bool, False), "is_in": ArraySpec(("M",), bool, False),
    "event_t": ArraySpec((N_ACTIONS,), float, -np.inf), "supported": ArraySpec((), bool, False),
    "last_motion": ArraySpec(), "jolted": ArraySpec((), bool, False),
    "unseen_in_view": ArraySpec((), np.int32, 0), "push_decided": ArraySpec((), float, -np.inf),
    "holds": ArraySpec((HOLD_FIELDS,), float, np.nan), "jitter": ArraySpec((3,)),
}
"""The arrays every particle state holds besides the core ones (poses, velocities, parameters, modes,
log-weights): relations, events and episodes, the negative evidence's count, the teleports' noise.
The mechanisms declare theirs (:attr:`~estimator.model.mechanisms.base.Mechanism.arrays`)."""


class ParticleState:
    """The state of K particles over M objects (positions in metres, quaternions x, y, z, w).

    * ``poses (K, M, 7)``, ``velocities (K, M, 6)`` (linear m/s, angular rad/s);
    * ``params (K, M, 5)``: lateral / rolling / spinning friction, restitution, mass (kg);
    * ``modes (K, M)`` int8, FREE / HELD (:mod:`actions.modes`);
    * ``log_weights (K,)``: unnormalised, the largest finite one 0;
    * ``on_top (K, M, M+1)``, ``is_in (K, M, M)`` bool: relations at the last update (column M of
      ``on_top`` is the floor);
    * ``event_t (K, M, 4)``: time (s) of each particle's latest Pick / Place / Release / Push per
      object (-inf: none; see :func:`actions.events.record_event_times`);
    * ``push_decided (K, M)``: time (s) at which the latest Push was decided (the object let go;
      -inf: none), from which it counts as recent (:func:`actions.events.recent_events`);
    * ``holds (K, M, 6)``: per object, its height when it last rested free and the record of its
      current held episode (Pick time, smoothed and highest height, held airborne, let go pending
      confirmation; :mod:`actions.push`);
    * ``supported (K, M)`` bool: resting on or in something at the last update;
    * ``last_motion (K, M)``: distance (m) each object moved in the last update;
    * ``jolted (K, M)`` bool: objects displaced without physics since the worlds last saw them (to
      be pushed out of anything they interpenetrate before stepping);
    * ``unseen_in_view (K, M)`` int32: updates since its last detection in which a held object in a
      tracked hand was in the camera's view and not detected (the hand-occlusion term's memory);
    * ``let_go_unseen (K, M)``: time (s) at which the particle let the object go when it stopped
      being perceived (-inf: never); its fall happened unseen, in the ``t_perceived`` before;
    * ``hold_error (K, M, 3)``: m, how far a held, undetected object following a tracked hand is from
      the hand plus its offset at the last detection (:func:`estimator.worlds.held.hand_offset_walk`).
    * ``hidden_at (K, M, 3)`` m, ``hidden_t (K, M)`` s, ``hidden_n (K, M)`` int32: a uniform sample of
      where (and when) a held object was while its tracked hand kept it out of the camera's view, over
      the ``hidden_n`` updates it was (:func:`estimator.model.hidden.hidden_places`); ``down_at (K, M, 3)``,
      ``down_t (K, M)``: where and when it was lowest over those updates (where it would have been
      put down: :func:`estimator.model.hidden.lowest_hidden_place`); ``rest_at (K, M, 3)`` m, ``rest_t
      (K, M)`` s (-inf: none): where and when it last rested on a support out of view, undetected
      (where a hand that sets it down leaves it: :func:`estimator.model.hidden.resting_place`).
    * ``jitter (K, M, 3)`` m: the horizontal perception noise the last update's teleport added to
      each free object's position (zero for objects it did not teleport, held ones, and vertically:
      a support undoes it): what the particle's next prediction of a detection leaves out, so that it
      is scored on its physics, not on that draw.
    * ``push_grip (K, M)``: in [0, 1], how the contact of the hand that pushes an object out of view
      slides (1 frictionless, 0 gripped; :func:`estimator.model.holding.slide_around_hand`); NaN when no
      such push is out of view.
    """

    def __init__(self, **arrays: np.ndarray):
        self.__dict__.update(arrays)

    @property
    def names(self) -> tuple[str, ...]:
        """The names of the state's arrays, in the order they were given."""
        return tuple(self.__dict__)

    @classmethod
    def initial(cls, K: int, M: int, core: dict[str, np.ndarray], declared: dict[str, ArraySpec]) -> "ParticleState":
        """The state of K particles over M objects from the ``core`` arrays given (poses, velocities,
        parameters, modes, log-weights, by name) and every other array from its declaration
        (:class:`~estimator.model.mechanisms.base.ArraySpec`: :data:`ARRAYS` and the mechanisms')."""
        arrays = dict(core)
        for name, spec in declared.items():
            if name not in arrays:
                arrays[name] = spec.make(K, M)
        return cls(**arrays)

    def replace(self, **arrays: np.ndarray) -> "ParticleState":
        """A new state with the arrays named in ``arrays`` replaced (the others shared, not copied)."""
        unknown = set(arrays) - set(self.__dict__)
        if unknown:
            raise KeyError(f"the particle state holds no array named {sorted(unknown)}")
        return ParticleState(**{**self.__dict__, **arrays})

    def after_update(self, move, settled, log_weights: np.ndarray, unseen_in_view: np.ndarray, free: np.ndarray,
                     **declared: np.ndarray) -> "ParticleState":
        """The particles after an update from this state: ``move`` (:class:`~estimator.model.step.Move`)
        and ``settled`` (:class:`~estimator.model.step.Settled`) of the update, ``log_weights (K,)`` (the
        largest finite one made 0), ``unseen_in_view (K, M)``, ``free (K, M)`` bool: the entries free
        after it (the others keep no teleport jitter: they are at their target); ``declared``: the
        mechanisms' arrays after the update, by name (:meth:`~estimator.model.mechanisms.base.Mechanism.commit`)."""
        K, M = free.shape
        return self.replace(
            poses=settled.poses, velocities=settled.velocities, modes=settled.modes,
            log_weights=log_weights - np.max(log_weights[np.isfinite(log_weights)]), on_top=settled.on_top,
            is_in=settled.is_in, supported=settled.supported,
            last_motion=np.linalg.norm(settled.poses[..., :3] - move.poses[..., :3], axis=-1),
            jolted=np.zeros((K, M), dtype=bool), unseen_in_view=unseen_in_view, holds=settled.holds,
            jitter=move.jitter * free[..., None], **declared)

    def take(self, ancestors: np.ndarray, own: np.ndarray | None = None) -> "ParticleState":
        """The particles ``ancestors (K,)`` (indices, repeats allowed), copied, equally weighted.

        Objects ``own (M,)`` bool keep each particle's own pose, velocity, parameters and relations
        (as subject), not the ancestor's: nothing weighed them (see
        :meth:`~estimator.model.SceneModel.before_resampling`), so resampling them with the others would
        only lose their spread. Those in or on another object (``is_in``, ``on_top`` of the particle
        before) are carried rigidly from that support's pose in the particle to its pose in the
        ancestor."""
        out = ParticleState(**{name: value[ancestors].copy() for name, value in self.__dict__.items()})
        out.log_weights = np.zeros(len(ancestors))
        if own is None or not np.any(own):
            return out
        idx = np.flatnonzero(own)
        n = min(len(ancestors), len(self.poses))  # rows beyond the old K keep the ancestor's values
        for name in ("poses", "velocities", "params", "supported", "on_top", "is_in"):
            getattr(out, name)[:n, idx] = getattr(self, name)[:n, idx]
        M = self.poses.shape[1]
        support = self.is_in[:n, idx] | self.on_top[:n, idx, :M]  # (n, len(idx), M)
        k, j = np.nonzero(support.any(axis=-1))
        if len(k):
            m, c = idx[j], np.argmax(support[k, j], axis=-1)  # each one's first support, as an index
            out.poses[k, m] = carry_pose(self.poses[k, m], self.poses[k, c], out.poses[k, c])
        return out
