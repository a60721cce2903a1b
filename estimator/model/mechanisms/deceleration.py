"""Deceleration evidence: an object seen rolling (or sliding) along its support, teleported in motion,
is weighed on how fast each particle's physics slowed it down over its last update against the
deceleration fitted through all its detections since it was first seen so
(:func:`~estimator.model.tracks.fit_acceleration`).

A teleport in motion gives every particle the perceived velocity again at every update, so neither the
position nor one update's velocity says much about a ball's rolling friction: over 80 ms a friction
twice as large changes the velocity by 2 cm/s, under the noise of a velocity fitted through a few
detections. The deceleration fitted through a second of detections is known to a few cm/s^2
(its standard error falls as the span to the power 5/2), and it is what decides where a ball that
rolls out of view stops. Consecutive updates fit overlapping detections: each weighs the fit with
the share of its information that is new, ``5 dt / T`` over a span T (the information about a
constant acceleration grows as ``T^5``), so that the terms of a whole roll add up to what its
detections say once. Part of the full model (``moving_teleports``, with ``decel_error`` above 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from actions.modes import is_free

from ...state import ArraySpec
from ..likelihood import acceleration_log_likelihood
from ..motion import rolled_along
from ..weighing import mean_innovation
from .base import Draft, Mechanism

DECEL_FLOOR = 0.02
"""m/s^2: the least standard deviation of a perceived deceleration (an object rolling freely, whose
fitted deceleration is near zero, is still weighed with some tolerance for the physics' error)."""


CHANGE_CHI2 = 9.21
"""The 99 % quantile of a chi-square of two degrees of freedom: the test that a roll's deceleration
changed (:meth:`DecelerationEvidence._fit`)."""


class DecelerationEvidence(Mechanism):
    """Keeps each particle's horizontal velocity at the start of its last update (``roll_v0 (K, M, 2)``
    m/s, NaN before the first) and weighs, at the next one, the deceleration its physics gave each
    object seen rolling along its support at both (free in the particle) against the perceived one
    (:func:`~estimator.model.likelihood.acceleration_log_likelihood`)."""

    arrays = {"roll_v0": ArraySpec((2,), float, np.nan)}

    def __init__(self, model):
        super().__init__(model)
        M = len(model.scene.objects)
        self._since = np.full(M, np.nan)  # s: the update since which each object is seen rolling along
        self._dt_prev = math.nan
        # this update's check, for the term: (mask (K, M), particles' accelerations (K, M, 2),
        # perceived (M, 2), their std (M,), temper (M,)); None: nothing checked
        self.weighed: tuple | None = None
        # (M,): :func:`~estimator.model.weighing.mean_innovation` of this update's check (NaN: none).
        # Every particle slowing a ball down the same wrong way widens its frictions' kernel at the
        # next resampling (:meth:`after_weighing` hands it to the model's surprise)
        self.surprise = np.full(M, np.nan)

    def terms(self) -> tuple:
        return (DecelerationTerm(self, self.model.config.noise.outlier_prob),)

    def perceive(self, u: Draft) -> None:
        mem, nz = self.model.memory, self.model.config.noise
        # seen rolling along its support and teleported in motion (as for the velocity evidence): put
        # back on its detections, the particles' physics alone did not follow it
        along = u.moving & ~u.falling & mem.perceived_prev & rolled_along(mem.previous_tick_velocity())
        self._since[~along] = np.nan
        self._since[along & np.isnan(self._since)] = u.t  # not before: a flicked ball slides, then rolls
        self.weighed = None
        v0 = u.state.roll_v0
        if along.any() and self._dt_prev > 0:
            M = len(along)
            seen, std, temper = np.zeros((M, 2)), np.ones(M), np.zeros(M)
            ok = np.zeros(M, dtype=bool)
            for m in np.flatnonzero(along):
                fit = self._fit(int(m))
                if fit is None:
                    continue
                a, se, span = fit
                ok[m] = True
                seen[m] = a
                std[m] = math.sqrt(se * se + (nz.decel_error * float(np.linalg.norm(a))) ** 2 + DECEL_FLOOR ** 2)
                temper[m] = min(1.0, 5.0 * self._dt_prev / span)
            if ok.any():
                accel = (u.state.velocities[..., :2] - v0) / self._dt_prev
                mask = ok[None, :] & is_free(u.prev_modes) & np.all(np.isfinite(v0), axis=-1)
                self.weighed = (mask, accel, seen, std, temper)
                # how far every particle is from the roll, for the model's surprise (not averaged
                # over updates, as the model's is: the fit is over the whole roll already)
                self.surprise = mean_innovation(u.state.log_weights, mask, accel, seen, std)

    def _fit(self, m: int) -> tuple | None:
        """Object m's deceleration since it is seen rolling (:meth:`~estimator.model.perception_memory
        .PerceptionMemory.acceleration`), over its detections while the deceleration stayed constant:
        where the fit over the later half of the span disagrees with the whole span's (a flicked ball
        slides before it rolls, slowing down several times faster), the earlier half is dropped for
        good (a chi-square test on the difference of the nested fits, whose variance is the
        difference of theirs)."""
        mem, std = self.model.memory, self.model.config.noise.position_std
        fit = mem.acceleration(m, float(self._since[m]), std)
        if fit is None:
            return None
        a, se, span = fit
        half = mem.acceleration(m, float(mem.last_seen[m]) - 0.5 * span, std)
        if half is not None and half[1] > se:
            d = half[0] - a
            if float(d @ d) / (half[1] ** 2 - se ** 2) > CHANGE_CHI2:
                self._since[m] = float(mem.last_seen[m]) - 0.5 * span
                return half
        return fit

    def after_weighing(self, ev, log_weights: np.ndarray) -> None:
        """The model's surprise is the larger of the velocities' (the velocity evidence's, before this
        in the list) and this update's deceleration check's."""
        if self.weighed is not None:
            checked = self.weighed[0].any(axis=0) & np.isfinite(self.surprise)
            self.model.surprise[checked] = np.maximum(self.model.surprise[checked], self.surprise[checked])

    def commit(self, state, p, w, rng) -> dict:
        self._dt_prev = float(p.dt)
        return {"roll_v0": np.asarray(p.move.velocities[..., :2], dtype=float).copy()}


@dataclass(frozen=True)
class DecelerationTerm:
    """The log-weight term of :class:`DecelerationEvidence` (``mechanism``): the deceleration each
    particle's physics gave the objects checked at this update against the perceived one
    (:func:`~estimator.model.likelihood.acceleration_log_likelihood`, only where the object is still
    free in the particle); zero when nothing was checked."""

    mechanism: DecelerationEvidence
    outlier_prob: float

    def __call__(self, ev) -> np.ndarray:
        check = self.mechanism.weighed
        if check is None:
            return np.zeros(len(ev.poses))
        mask, accel, seen, std, temper = check
        return acceleration_log_likelihood(accel, seen, std, mask & is_free(ev.modes), temper, self.outlier_prob)
