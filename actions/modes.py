"""The hybrid mode model: each object is FREE (moved by physics) or HELD (moved by an agent).

Mode switches are the human actions the system infers:

====================  ==================================  ========
previous -> new       condition                           event
====================  ==================================  ========
FREE -> HELD          (perceived or not)                  Pick
HELD -> FREE          let go resting on a support         Place
HELD -> FREE          let go in the air (drop, throw)     Release
FREE -> HELD -> FREE  moved along its support, never      Push
                      lifted, let go on it
====================  ==================================  ========

A Push is decided when the object is let go (:mod:`actions.push`: a Place of an object that was
never lifted becomes a Push at the time of its Pick, and that Pick is withdrawn).

The functions work on arrays of any shape (one scene ``(M,)`` or particles ``(K, M)``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FREE = np.int8(0)
HELD = np.int8(1)


@dataclass(frozen=True)
class Mode:
    """One mode of the hybrid model: its code in the ``int8`` mode arrays, its name and who moves an
    object in it (``by_agent``: an agent sets its pose and physics does not move it; otherwise
    physics does)."""

    code: np.int8
    name: str
    by_agent: bool


MODES = (Mode(FREE, "free", by_agent=False), Mode(HELD, "held", by_agent=True))
"""The registry of modes, indexed by code. Code asks what a mode means through :func:`is_held` /
:func:`is_free` (or :data:`MODES`), never by comparing codes, so that a new mode is one entry here."""

_BY_AGENT = np.array([m.by_agent for m in MODES], dtype=bool)
if any(int(m.code) != i for i, m in enumerate(MODES)):
    raise ImportError("actions.modes.MODES must be indexed by code")


def is_held(modes) -> np.ndarray:
    """``bool``, the shape of ``modes`` (int8 codes, any shape): objects moved by an agent."""
    return _BY_AGENT[np.asarray(modes)]


def is_free(modes) -> np.ndarray:
    """``bool``, the shape of ``modes`` (int8 codes, any shape): objects moved by physics."""
    return ~_BY_AGENT[np.asarray(modes)]

NO_EVENT = 0
PICK = 1
PLACE = 2
RELEASE = 3
PUSH = 4
EVENT_NAMES = {PICK: "Pick", PLACE: "Place", RELEASE: "Release", PUSH: "Push"}
"""Event code -> action name; codes are 1, 2, ... so that column ``code - 1`` of an event-time array
``(..., M, len(EVENT_NAMES))`` holds that action's times."""


def switch_events(previous: np.ndarray, new: np.ndarray, supported: np.ndarray) -> np.ndarray:
    """Event codes (``int8``, same shape) for the mode switches ``previous -> new``.

    ``supported`` says whether the object rests on or in something when it is let go; it broadcasts
    against the modes. Codes: :data:`NO_EVENT`, :data:`PICK`, :data:`PLACE`, :data:`RELEASE`
    (Pushes are Places reclassified afterwards, :func:`actions.push.end_codes`).
    """
    previous = np.asarray(previous)
    new = np.asarray(new)
    supported = np.broadcast_to(np.asarray(supported, dtype=bool), new.shape)
    out = np.zeros(new.shape, dtype=np.int8)
    out[is_free(previous) & is_held(new)] = PICK
    released = is_held(previous) & is_free(new)
    out[released & supported] = PLACE
    out[released & ~supported] = RELEASE
    return out


def merge_events(*codes: np.ndarray) -> np.ndarray:
    """Combine event-code arrays of successive switches in one update (the first non-zero wins)."""
    out = np.zeros_like(codes[0])
    for c in codes:
        out = np.where(out == NO_EVENT, c, out)
    return out


@dataclass(frozen=True)
class ModePriors:
    """Prior probabilities of mode switches, per object and update.

    * ``pick`` (FREE -> HELD) and ``place`` (HELD -> FREE while perceived) are triggered by evidence
      (a divergence, a perceived put-down); a particle that makes the switch pays ``log(pick)`` or
      ``log(place)`` in its weight, one that does not pays ``log(1 - p)``.
    * ``release_on_loss``: probability that a held object was let go when it stops being perceived
      (sampled: that fraction of the particles releases it, the rest keep it held);
      ``release``: probability per update that a held, unperceived object is let go later.
      Releases are drawn from these priors, so they cost nothing in the weights.
    * ``release_on_loss_carried`` / ``release_on_loss_still``: the same when the hand that held
      the object is tracked and has moved more than ``carry_distance`` (m) since the object was last
      seen (it is carrying it: people rarely drop what they carry) / has not (it may have put it
      down, or let it fall: a hand in plain view that no longer shows its object is evidence that
      negative evidence weighs, see ``NoiseConfig.hand_occlusion``). The defaults are fitted on the
      simulator's scenarios (``scene-estimator fit-priors``, on seeds the evaluation does not use):
      the fraction of such losses where the object had in truth been let go.
    * ``release_hidden``: probability that an object its tracked hand carried out of view, and did
      not let go when it was lost, was let go while the hand hid it: weighed when the hand shows in
      view again without it (:func:`estimator.model.hidden.release_behind_cover`). Fitted the same way.
    * ``put_down_hidden``: probability that an object let go while its hand hid it was put down (it
      came to rest where it was let go), not dropped: the particle then lets it go where it was
      lowest while hidden (a person puts a thing down by lowering it;
      :func:`estimator.model.hidden.lowest_hidden_place`), at that time, and the event is a Place;
      otherwise at a uniform sample of its hidden places, a Release. Fitted the same way.
    * ``put_down_touched``: probability that an object its tracked hand carried out of view, and that
      rested on a support where it was lowest there, was let go there when the hand lifts away
      (carries it more than ``carry_distance`` above that place): the particle then puts it down
      there, at that time, a Place (:func:`estimator.model.hidden.set_down_behind_cover`), without waiting
      for the hand to show in view without it. Fitted the same way.
    * ``held_out_of_reach``: probability that an object held by an agent is detected farther than
      :data:`~estimator.model.hand_memory.HAND_RADIUS` from every hand tracked in that frame (a hand
      nobody tracks moves it); a particle that holds such an object pays its log at every update
      (:func:`estimator.model.likelihood.hand_reach_log_likelihood`), so an object flicked or pushed and
      then left to roll is not followed as if carried. Fitted the same way, over the frames where an
      object is held in truth, detected, and a hand is tracked.
    * ``let_go_moving``: the proposal rate of a let-go in motion: each update, a held object seen
      moving along its support (faster than 0.2 m/s, not falling) with no tracked hand within reach
      is let go in that fraction of the particles that hold it (a ball flicked or pushed and then
      left to roll: physics takes it on from its velocity). The switch is a Place while perceived,
      whose prior ``place`` the weights keep: the proposal is corrected for (importance weights), so
      this sets how many particles try it, not how likely it is (0: never tried; paper mode). (An
      object at rest that starts moving with no tracked hand within reach is not held at all: see
      ``Move.set_moving``.)
    """

    pick: float = 0.02
    place: float = 0.2
    release: float = 0.01
    release_on_loss: float = 0.5
    # fitted on carried losses of held objects: 0 of 40 (Laplace); a thrown ball, whose every loss is a
    # release, is not carried (fit-priors counts it as such: 59 of 160 with both engines)
    release_on_loss_carried: float = 0.024
    release_on_loss_still: float = 0.5  # fitted: no such loss in the scenarios of either engine (Laplace: 0.5)
    release_hidden: float = 0.214  # fitted: fit-priors, both engines, 21 of 101
    put_down_hidden: float = 0.957  # fitted: fit-priors, both engines, 21 of the 21 let go while hidden were put down
    put_down_touched: float = 0.976  # fitted: fit-priors, both engines, 40 of the 40 set down out of view were let go
    held_out_of_reach: float = 3e-05  # fitted: fit-priors, both engines, 0 of 33752 frames
    let_go_moving: float = 0.2
    carry_distance: float = 0.05

    def __post_init__(self):
        if not (isinstance(self.carry_distance, (int, float)) and 0 <= self.carry_distance < float("inf")):
            raise ValueError(f"ModePriors.carry_distance must be >= 0 metres, got {self.carry_distance!r}")
        for name in ("pick", "place", "release", "release_on_loss", "release_on_loss_carried",
                     "release_on_loss_still", "release_hidden", "put_down_hidden", "put_down_touched", "held_out_of_reach",
                     "let_go_moving"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"ModePriors.{name} must be in [0, 1], got {v}")

    def log_prior_cost(self, previous: np.ndarray, new: np.ndarray, perceived: np.ndarray) -> np.ndarray:
        """Log-prior of the evidence-triggered switches (Pick, Place) for each object (same shape).

        Objects that could have switched and did not pay ``log(1 - p)``; unperceived held objects
        (whose releases are sampled from the prior) pay nothing.
        """
        previous = np.asarray(previous)
        new = np.asarray(new)
        perceived = np.broadcast_to(np.asarray(perceived, dtype=bool), new.shape)
        p = np.ones(new.shape)
        free = is_free(previous)
        p = np.where(free & perceived, np.where(is_held(new), self.pick, 1.0 - self.pick), p)
        held_seen = is_held(previous) & perceived
        p = np.where(held_seen, np.where(is_free(new), self.place, 1.0 - self.place), p)
        with np.errstate(divide="ignore"):
            return np.log(p)
