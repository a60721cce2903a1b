"""What each particle's world holds, so that an update loads only what changed.

A :class:`~estimator.worlds.pool.WorldPool` owns one :class:`WorldCache` (``pool.cache``). The filter tells
it what the worlds produced (:meth:`WorldCache.hold`) and how resampling moved the particles between
slots, and changed their number (:meth:`WorldCache.follow`); before each run it asks which entries to
load (:meth:`WorldCache.loads`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["WorldCache"]


class WorldCache:
    """Two records per particle slot, for K particles of M objects:

    * what its world holds: poses ``(K, M, 7)`` and velocities ``(K, M, 6)`` as the last run left
      them, rows by slot (resampling does not move a world's content; NaN: load everything);
    * what the worlds produced, rows following the particles through resampling: a particle whose
      entry still equals what some world produced at rest may be loaded asleep.

    Empty (everything loads) until the first :meth:`hold`."""

    def __init__(self):
        self.poses: np.ndarray | None = None
        self.velocities: np.ndarray | None = None
        self._produced: tuple[np.ndarray, np.ndarray] | None = None
        self._placed: np.ndarray | None = None

    def loads(self, poses: np.ndarray, velocities: np.ndarray, fused: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
        """For the particles about to run, ``poses (K, M, 7)`` and ``velocities (K, M, 6)``:

        * ``reset (K, M)``: entries that differ from what their slot's world holds, to load;
        * ``settled (K, M)`` (None before the first :meth:`hold`): entries at rest (zero velocity)
          as a world produced them, which may be loaded asleep: a resampled particle's resting
          objects, and resting objects that only took a horizontal Kalman step towards their
          detection (``fused (K, M)``, millimetres along their support: waking them, and what they
          touch, would cost a settling of every such world at every step of the fusion); after an
          update of loads only, those the model placed at rest, where it placed them (:meth:`hold`'s
          ``at_rest``; copies of them too)."""
        K, M = poses.shape[:2]
        if self.poses is None:
            reset = np.ones((K, M), dtype=bool)
        else:
            reset = np.any(poses != self.poses, axis=-1) | np.any(velocities != self.velocities, axis=-1)
        if self._produced is None:
            return reset, None
        p, v = self._produced
        same = np.all(poses == p, axis=-1) & np.all(velocities == v, axis=-1)
        if self._placed is not None:  # after loads only: at rest only where placed so, exactly
            same &= self._placed
        elif fused is not None:  # set at rest by the fusion (mechanisms.rest_fusion), moved horizontally
            same |= fused & np.all(poses[..., 2:] == p[..., 2:], axis=-1)
        return reset, np.all(velocities == 0.0, axis=-1) & same

    def hold(self, poses: np.ndarray, velocities: np.ndarray, lost: np.ndarray | None = None,
             at_rest: np.ndarray | None = None) -> None:
        """The worlds now hold ``poses (K, M, 7)`` and ``velocities (K, M, 6)`` (kept, not copied),
        except the slots ``lost (K,)`` (an exploded simulation, a dead worker), which load in full.
        ``at_rest (K, M)`` bool: after an update that stepped nothing (loads only), the entries known
        to be at rest where they were loaded (placed so by the model); until the next hold, only
        they count as settled, where they are (:meth:`loads`: a world that never stepped made
        nothing at rest). None: after an update that stepped."""
        self.poses, self.velocities = poses, velocities
        self._produced = (poses.copy(), velocities)
        self._placed = at_rest
        if lost is not None and np.any(lost):
            self.poses[lost] = np.nan

    def follow(self, ancestors: np.ndarray, at_rest: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Particle ``i`` is now a copy of particle ``ancestors[i]`` (``(n,)``, resampling); the
        worlds keep what they hold. When ``n`` differs from the particles before, the slots beyond
        the old count hold nothing known (they load in full) and those beyond ``n`` are forgotten
        (the pool parks their worlds). ``at_rest``: entries ``(n, M)`` bool that are now at rest at
        poses ``(n, M, 7)`` no world produced, as surely as if one had (an object carried with the
        support it rests on, :func:`~estimator.model.regularisation.carried_at_rest`): taken as
        produced at rest."""
        if self._placed is not None:
            self._placed = self._placed[ancestors]
        if self._produced is not None:
            self._produced = (self._produced[0][ancestors], self._produced[1][ancestors])
            if at_rest is not None and np.any(at_rest[0]):
                mask, poses = at_rest
                self._produced[0][mask] = poses[mask]
                self._produced[1][mask] = 0.0
        n = len(ancestors)
        if self.poses is None or n == len(self.poses):
            return
        keep = min(len(self.poses), n)
        poses = np.full((n,) + self.poses.shape[1:], np.nan)
        velocities = np.full((n,) + self.velocities.shape[1:], np.nan)
        poses[:keep], velocities[:keep] = self.poses[:keep], self.velocities[:keep]
        self.poses, self.velocities = poses, velocities
