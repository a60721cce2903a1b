"""The particles: a structure of arrays, K particles by M objects."""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from physics.transforms import carry_pose


@dataclass
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
      the hand plus its offset at the last detection (:func:`estimator.held.hand_offset_walk`).
    * ``hidden_at (K, M, 3)`` m, ``hidden_t (K, M)`` s, ``hidden_n (K, M)`` int32: a uniform sample of
      where (and when) a held object was while its tracked hand kept it out of the camera's view, over
      the ``hidden_n`` updates it was (:func:`estimator.holding.hidden_places`); ``down_at (K, M, 3)``,
      ``down_t (K, M)``: where and when it was lowest over those updates (where it would have been
      put down: :func:`estimator.holding.lowest_hidden_place`); ``rest_at (K, M, 3)`` m, ``rest_t
      (K, M)`` s (-inf: none): where and when it last rested on a support out of view, undetected
      (where a hand that sets it down leaves it: :func:`estimator.holding.resting_place`).
    * ``jitter (K, M, 3)`` m: the horizontal perception noise the last update's teleport added to
      each free object's position (zero for objects it did not teleport, held ones, and vertically:
      a support undoes it): what the particle's next prediction of a detection leaves out, so that it
      is scored on its physics, not on that draw.
    * ``push_grip (K, M)``: in [0, 1], how the contact of the hand that pushes an object out of view
      slides (1 frictionless, 0 gripped; :func:`estimator.holding.slide_around_hand`); NaN when no
      such push is out of view.
    """

    poses: np.ndarray
    velocities: np.ndarray
    params: np.ndarray
    modes: np.ndarray
    log_weights: np.ndarray
    on_top: np.ndarray
    is_in: np.ndarray
    event_t: np.ndarray
    supported: np.ndarray
    last_motion: np.ndarray
    jolted: np.ndarray
    unseen_in_view: np.ndarray
    hold_error: np.ndarray
    let_go_unseen: np.ndarray
    hidden_at: np.ndarray
    hidden_t: np.ndarray
    hidden_n: np.ndarray
    down_at: np.ndarray
    down_t: np.ndarray
    rest_at: np.ndarray
    rest_t: np.ndarray
    push_decided: np.ndarray
    holds: np.ndarray
    jitter: np.ndarray
    push_grip: np.ndarray

    def after_update(self, move, settled, log_weights: np.ndarray, unseen_in_view: np.ndarray,
                     hidden: tuple[np.ndarray, ...], free: np.ndarray) -> "ParticleState":
        """The particles after an update from this state: ``move`` (:class:`~estimator.step.Move`)
        and ``settled`` (:class:`~estimator.step.Settled`) of the update, ``log_weights (K,)`` (the
        largest finite one made 0), ``unseen_in_view (K, M)``, ``hidden``: the seven arrays of
        :func:`~estimator.holding.places_after_update`; ``free (K, M)`` bool: the entries free
        after it (the others keep no teleport jitter: they are at their target)."""
        K, M = free.shape
        return ParticleState(
            poses=settled.poses, velocities=settled.velocities, params=self.params, modes=settled.modes,
            log_weights=log_weights - np.max(log_weights[np.isfinite(log_weights)]), on_top=settled.on_top,
            is_in=settled.is_in, event_t=self.event_t, supported=settled.supported,
            last_motion=np.linalg.norm(settled.poses[..., :3] - move.poses[..., :3], axis=-1),
            jolted=np.zeros((K, M), dtype=bool), unseen_in_view=unseen_in_view,
            hold_error=move.hold_error, let_go_unseen=move.let_go_unseen, hidden_at=hidden[0],
            hidden_t=hidden[1], hidden_n=hidden[2], down_at=hidden[3], down_t=hidden[4],
            rest_at=hidden[5], rest_t=hidden[6], push_decided=self.push_decided, holds=settled.holds,
            jitter=move.jitter * free[..., None], push_grip=(move.push_grip if move.push_grip is not None
                                                         else np.full((K, M), np.nan)))

    def take(self, ancestors: np.ndarray, own: np.ndarray | None = None) -> "ParticleState":
        """The particles ``ancestors (K,)`` (indices, repeats allowed), copied, equally weighted.

        Objects ``own (M,)`` bool keep each particle's own pose, velocity, parameters and relations
        (as subject), not the ancestor's: nothing weighed them (see
        :meth:`~estimator.filter.SceneEstimator._resample`), so resampling them with the others would
        only lose their spread. Those in or on another object (``is_in``, ``on_top`` of the particle
        before) are carried rigidly from that support's pose in the particle to its pose in the
        ancestor."""
        out = ParticleState(*(getattr(self, f.name)[ancestors].copy() for f in fields(self)))
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
