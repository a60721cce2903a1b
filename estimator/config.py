"""Configuration of the estimator: frozen dataclasses with checked, documented defaults.

:class:`EstimatorConfig` bundles its sections (:mod:`estimator.config_sections`:
:class:`ReasonerConfig`, the parameters of the IROS 2019 physics reasoner, its Table I;
:class:`NoiseConfig`, the perturbations of the particle filter, all zero in the paper's reasoner;
:class:`HandConfig`, :class:`AdaptiveConfig`) with the particle count, resampling and output settings.

Configuration files (YAML or JSON) name the fields to change; everything else keeps its default::

    particles: 64
    noise: {position_std: 0.02, motion_noise: 0.5}
    reasoner: {horizon: 0.1}

:func:`load_config` reads one (errors name the file, line and field), :func:`config_to_dict` writes
the full configuration in the same form (``scene-estimator config`` prints it).
"""
from __future__ import annotations

import math
import os
import re
import typing
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

from actions.modes import ModePriors
from physics.errors import ConfigError
from physics.fields import _Fields, read_yaml_with_lines
from physics.world import PhysicsSettings

from .config_sections import AdaptiveConfig, BudgetConfig, HandConfig, NoiseConfig, ReasonerConfig
from .relations import RelationConfig

SOLVER_RESIDUAL = 1e-6
"""(m/s)^2: the particle worlds' Bullet solver stops iterating when the squared velocity
corrections of a sweep over the contacts sum to less than this (Bullet's residual is
the change of impulse times the constraint's inverse effective mass: a velocity). At 1e-6 what the
solver leaves unresolved is about 1 mm/s, a fifth of the speed at which the worlds call an object at
rest (:data:`~estimator.worlds.resting.REST_SPEED`, 5 mm/s). At 1e-4 (1 cm/s, twice that speed and a
quarter of what gravity adds in one step) the solver stops after about one sweep: a body resting
on a few points of a mesh (pybullet_data's duck) is kicked whenever the filter moves it along its
support (regularisation, process noise), rocks, and tips over in most particles while the true one
stands (``tests/test_config.py``)."""

__all__ = ["AdaptiveConfig", "BudgetConfig", "EstimatorConfig", "HandConfig", "NoiseConfig", "ReasonerConfig",
           "config_from_dict", "config_to_dict", "default_config", "load_config", "reasoning_due",
           "with_adaptive_count", "with_budget", "budget_cap", "SOLVER_RESIDUAL"]


def reasoning_due(t_last: float | None, t: float, horizon: float) -> bool:
    """Whether a frame at ``t`` (s) starts a reasoning step, the last one having run at ``t_last``
    (None: none yet): at the first frame, then once ``horizon`` seconds of stream time have passed
    (``ReasonerConfig.horizon``)."""
    return t_last is None or t >= t_last + horizon - 1e-9


def budget_cap(cap: int, K: int, seconds: float, scaled: float, covered: float, config: BudgetConfig,
               most: int) -> int:
    """The particle cap after a reasoning step that took ``seconds`` (wall time) with ``K`` particles
    to cover ``covered`` s of stream time (> 0), ``scaled`` s of it in work that scales with K (the
    particle worlds; the rest, the main process's model and belief, taken as fixed), the cap having
    been ``cap``; ``most``: the count configured.

    The budget is ``config.load * covered``; the K it affords, ``K * (budget - fixed) / scaled``
    (``fixed = seconds - scaled``). A step over the budget lowers the cap to that K (if lower); one
    under ``config.slack`` times it raises the cap to ``K`` times ``min(config.grow, afforded / K)``
    (if higher); otherwise the cap stays. Always within ``[min(config.min_particles, most), most]``
    (a budget the fixed work alone exceeds leaves the minimum)."""
    if not covered > 0:
        raise ValueError(f"budget_cap: the stream time covered must be > 0, got {covered!r}")
    seconds = max(seconds, 0.0)
    scaled = min(max(scaled, 0.0), seconds)
    budget = config.load * covered
    room = budget - (seconds - scaled)  # what the budget leaves the worlds
    afford = K * room / scaled if scaled > 0 else (math.inf if room > 0 else 0.0)
    lo = min(config.min_particles, most)
    if seconds > budget:
        cap = min(cap, int(max(afford, 0.0)))
    elif seconds < config.slack * budget:
        cap = max(cap, math.ceil(K * min(config.grow, afford / K)))
    return int(min(max(cap, lo), most))


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything the estimator needs besides the scene.

    * ``particles``: number of particle worlds K (1 with :meth:`NoiseConfig.off` is paper mode);
      with ``adaptive.enabled``, the count the filter starts with (clipped to its bounds).
    * ``adaptive``: a particle count that follows the belief's spread (:class:`AdaptiveConfig`).
    * ``budget``: live use: the count is capped so that the steps keep up with the stream
      (:class:`BudgetConfig`).
    * ``workers``: worker processes holding the particle worlds (0 = in this process; results do
      not depend on it).
    * ``worlds``: pybullet clients the K particle worlds are packed into, side by side (at most K;
      each costs about 28 MB, each particle a fraction of a megabyte more; a worker holds whole
      clients, so more workers than clients are idle). Results depend on it, never on ``workers``.
    * ``resample_threshold``: resample when the effective sample size falls below this fraction of K.
    * ``event_threshold``: an event enters the timeline when its probability exceeds this.
    * ``event_window`` (s): an event's probability is the weight of the particles that made that
      switch within this window (particles carry their event times through resampling).
    * ``negative_evidence``: particles that put an unperceived object in plain view of the camera
      lose weight (needs a camera in the scene).
    * ``follow_hands``: a held object that is not detected follows the tracked hand nearest to it
      when last detected (the paper's reasoner ignores hands: off in paper mode).
    * ``hands``: how tracked hands and held objects' offsets to them are read (:class:`HandConfig`).
    * ``lazy_checks``: test an object's divergence only when it could have crossed the threshold
      since the last test (see :func:`~estimator.worlds.propagate.propagate`); off in paper mode, which
      tests after every step. Reading poses back is most of the estimator's cost over bare stepping.
    * ``fresh_checks``: only objects detected since the previous update are tested for divergence
      (a released object is not pulled back to where it was last seen); the paper tests every object
      seen within ``t_perceived`` (off in paper mode).
    * ``moving_teleports``: an object teleported to a detection while it was tracked at the previous
      update (not a first sighting, nor a re-sighting after a loss) and moving along its support
      (vertical speed under 0.2 m/s, ``motion.MOVING_MAX_VERTICAL_SPEED``: not falling) keeps moving: it gets its
      perceived velocity over the reasoning period (and keeps its particle's spin), and its divergence
      test compares it with its detection carried on at that velocity through the update (Algorithm 2
      teleports at rest and Algorithm 1 tests against the fixed detection: off in paper mode, where a
      moving object that leaves view stops where it was last seen). A moving object that leaves view
      then goes on as physics says.
    * ``still_unacted``: an object detected still (no motion onset since it was last at rest)
      that diverges in a particle where it had rested, or where it is seen on a support (not one
      held still in the air), was moved by that particle's physics (knocked by something the
      particle let fall), not by an agent: its held episode is silent, no Pick and no Place or Push
      at its end (the paper reports a Pick for every divergence: off in paper mode).
    * ``one_action_per_motion``: a particle whose latest event is a Push since its object was seen
      to start moving has explained that motion; held again while the object is still seen moving
      (never at rest in between), it is the same push going on, not a new action (a box dragged
      along the table, which physics lets slide to rest before the hand stops, is held again to
      follow it: one Push, not a Push and a Pick; off in paper mode, which reports each divergence).
    * ``noise_aware_jumps``: a detection that jumped by more than ``d_perc_prev`` since the previous
      update teleports its object (Algorithm 1) only if two detections of a still object would be
      that far apart less than once in a thousand times, by the tracker's measured noise
      (:meth:`~estimator.model.perception_memory.PerceptionMemory.jumped`): a 1 cm tracker's
      detections of a resting object are more than 3.2 cm apart at one update in five, and every
      such jump would put the object on a noisy detection and wake what it touches. Below 5.6 mm of
      noise the threshold is ``d_perc_prev``, as in the paper (off in paper mode). The first
      sighting of an object the scene places is judged the same way, as a jump from that pose:
      within the noise, it is teleported horizontally only, each particle keeping the height and
      orientation its support gave it (a block of a stack, missed by the first frame and seen 9 mm
      above where it rests, is not put into its neighbours in every particle). And an object is
      teleported onto a fall off an edge (``moving_teleports``) only once it was seen moving, a
      motion onset beyond the noise: by their tick velocities, a 1 cm tracker's detections of a
      still tray read as sliding along and then falling at about one update in twenty, and each such
      teleport woke the tray and what shares its island in every particle.
    * ``freeze_unreachable``: with sleeping physics, objects at rest that nothing awake in their
      particle can reach within the update (:func:`~estimator.worlds.frozen.unreachable`: a bound on
      how far anything moves in it) are out of collision detection while the worlds step: a resting
      object costs Bullet nearly as much as a moving one otherwise. Exact while the bound holds
      (off in paper mode).
    * ``sleep_loads``: with sleeping physics, an object the update loaded into its world (teleported,
      copied by resampling, pushed out of penetration; not held at the update's start) that is at
      rest at both ends of the update is put to sleep then, as one it did not load is. Without,
      it stays awake for one more update, and keeps awake whatever it touches: a stack whose middle
      block was first seen late stayed awake in every world for two updates, in most for five (off
      in paper mode).
    * ``rest_prior``: the particles start where the scene's objects come to rest from the poses the
      scene gives them, settled once in one world (:func:`~estimator.model.prior.rest_prior`), for
      each object that comes to rest within three standard deviations of the perception noise
      (``noise.position_std``, ``noise.orientation_std``) of its given pose; the others (held in
      the air, say) keep the scene's pose. Otherwise an object given a pose it cannot rest in (a
      duck a few degrees off the tilt it stands at) settles in every particle at once, and the
      filter's jitter, which moves it without its contacts, pumps the swing until it tips over
      (off in paper mode). An object it rests flat on static bodies alone, that the first placement
      only slides along them, starts asleep in every world
      (:func:`~estimator.model.regularisation.placed_at_rest`).
    * ``physics``: the particle worlds' engine settings; the solver stops at a residual of
      :data:`SOLVER_RESIDUAL` (the ground-truth simulator keeps pybullet's 1e-7); URDFs are
      loaded without their visual meshes and textures (much less memory and start-up); objects at
      rest sleep (stepping skips them) until touched, reset or moved (see
      :func:`~estimator.worlds.propagate.propagate_batch`).
    * ``visibility_threshold``: fraction of an object's sample points in view for it to count as
      visible to the camera.
    * ``static_clip``: a held object's path to its target (a tracked hand, a detection carried on at
      its velocity) stops at the surface of static geometry it would enter
      (:meth:`physics.penetration.StaticGeometry.clip`), and the target of a free perceived object
      that the tracker's error sank into it is pushed out onto its surface, where it was seen
      horizontally (:meth:`~estimator.model.mechanisms.static_clip.StaticClip.lift_targets`): no
      particle ever believes an object inside the table or under the floor. Off in paper mode, which
      places an overridden object at its perceived pose wherever that is.
    """

    particles: int = 1
    workers: int = 0
    worlds: int = 8
    reasoner: ReasonerConfig = field(default_factory=ReasonerConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig.off)
    priors: ModePriors = field(default_factory=ModePriors)
    hands: HandConfig = field(default_factory=HandConfig)
    relations: RelationConfig = field(default_factory=RelationConfig)
    physics: PhysicsSettings = field(default_factory=lambda: PhysicsSettings(
        solver_residual_threshold=SOLVER_RESIDUAL, sleeping=True, collision_only=True))
    resample_threshold: float = 0.5
    event_threshold: float = 0.5
    event_window: float = 1.0
    negative_evidence: bool = True
    follow_hands: bool = True
    lazy_checks: bool = True
    fresh_checks: bool = True
    moving_teleports: bool = True
    still_unacted: bool = True
    one_action_per_motion: bool = True
    noise_aware_jumps: bool = True
    freeze_unreachable: bool = True
    sleep_loads: bool = True
    rest_prior: bool = True
    static_clip: bool = True
    visibility_threshold: float = 0.3
    hypothesis_min_p: float = 0.02
    adaptive: AdaptiveConfig = field(default_factory=AdaptiveConfig)
    budget: BudgetConfig = field(default_factory=BudgetConfig)

    def __post_init__(self):
        if not isinstance(self.particles, int) or self.particles < 1:
            raise ValueError(f"EstimatorConfig.particles must be an integer >= 1, got {self.particles!r}")
        if not isinstance(self.workers, int) or self.workers < 0:
            raise ValueError(f"EstimatorConfig.workers must be an integer >= 0, got {self.workers!r}")
        if not isinstance(self.worlds, int) or self.worlds < 1:
            raise ValueError(f"EstimatorConfig.worlds must be an integer >= 1, got {self.worlds!r}")
        if not self.event_window > 0:
            raise ValueError(f"EstimatorConfig.event_window must be > 0, got {self.event_window!r}")
        for n in ("resample_threshold", "event_threshold", "visibility_threshold",
                  "hypothesis_min_p"):
            v = getattr(self, n)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"EstimatorConfig.{n} must be in [0, 1], got {v!r}")

    @property
    def initial_particles(self) -> int:
        """The number of particles the filter starts with."""
        a = self.adaptive
        return min(max(self.particles, a.min_particles), a.max_particles) if a.enabled else self.particles

    @property
    def max_particles(self) -> int:
        """The most particles the filter may hold (its worlds' capacity)."""
        return self.adaptive.max_particles if self.adaptive.enabled else self.particles

    @property
    def varying_count(self) -> bool:
        """Whether K may change during a run (an adaptive count, a budget)."""
        return self.adaptive.enabled or self.budget.enabled

    @property
    def paper_mode(self) -> bool:
        """True when this configuration is the paper's reasoner (one world, no noise)."""
        return (self.particles == 1 and not self.varying_count and self.noise.is_off
                and self.priors.release_on_loss == 1.0)

    @classmethod
    def paper(cls, reasoner: ReasonerConfig | None = None) -> "EstimatorConfig":
        """The single-world, noise-free physics reasoner of Sallami et al. (2019)."""
        return cls(particles=1, noise=NoiseConfig.off(), reasoner=reasoner or ReasonerConfig(),
                   priors=ModePriors(release_on_loss=1.0, release_on_loss_carried=1.0, release_on_loss_still=1.0,
                                     let_go_moving=0.0),
                   negative_evidence=False, follow_hands=False, lazy_checks=False, fresh_checks=False,
                   moving_teleports=False, still_unacted=False, one_action_per_motion=False, static_clip=False,
                   noise_aware_jumps=False, freeze_unreachable=False, sleep_loads=False,
                   rest_prior=False)


def with_adaptive_count(config: EstimatorConfig, min_particles: int | None = None,
                        max_particles: int | None = None) -> EstimatorConfig:
    """``config`` with the adaptive particle count on (:class:`AdaptiveConfig`), between
    ``min_particles`` and ``max_particles`` (default: the configuration's bounds; a maximum under
    the configuration's minimum lowers the minimum with it). The filter starts from
    ``config.particles`` clipped to those bounds (:attr:`EstimatorConfig.initial_particles`)."""
    a = config.adaptive
    hi = a.max_particles if max_particles is None else max_particles
    lo = min(a.min_particles, hi) if min_particles is None else min_particles
    return replace(config, adaptive=replace(a, enabled=True, min_particles=lo, max_particles=hi))


def with_budget(config: EstimatorConfig, min_particles: int | None = None) -> EstimatorConfig:
    """``config`` with the live compute budget on (:class:`BudgetConfig`; ``min_particles``: its
    floor, default the configuration's)."""
    b = config.budget
    return replace(config, budget=replace(b, enabled=True, min_particles=b.min_particles if min_particles is None
                                          else min_particles))


SECTIONS: dict[str, type] = {"reasoner": ReasonerConfig, "noise": NoiseConfig, "priors": ModePriors,
                             "hands": HandConfig, "relations": RelationConfig, "physics": PhysicsSettings,
                             "adaptive": AdaptiveConfig, "budget": BudgetConfig}
"""The nested sections of :class:`EstimatorConfig`, by field name."""

BASES = ("paper", "particles")
"""What a configuration file starts from (its ``base`` field): the paper's reasoner
(:meth:`EstimatorConfig.paper`) or the particle filter with its default noise. Default: ``paper``
for one particle, ``particles`` for more."""


def default_config(particles: int = 1, base: str | None = None) -> EstimatorConfig:
    """The configuration a file (or the command line) starts from, for ``particles`` worlds."""
    base = base or ("paper" if particles == 1 else "particles")
    if base not in BASES:
        raise ValueError(f"base must be one of {', '.join(BASES)}, got {base!r}")
    if base == "paper":
        return replace(EstimatorConfig.paper(), particles=particles)
    return EstimatorConfig(particles=particles, noise=NoiseConfig())


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def config_to_dict(config: EstimatorConfig) -> dict[str, Any]:
    """Every field of ``config`` as plain YAML / JSON data (sections as nested mappings); reading it
    back with :func:`config_from_dict` gives ``config`` again."""
    out: dict[str, Any] = {}
    for f in fields(EstimatorConfig):
        value = getattr(config, f.name)
        if is_dataclass(value):
            out[f.name] = {g.name: _plain(getattr(value, g.name)) for g in fields(value)}
        else:
            out[f.name] = _plain(value)
    return out


def _parse_value(f: _Fields, value: Any, hint: Any, where: str) -> Any:
    """``value`` checked against the type annotation ``hint`` (float, int, bool, tuple of floats,
    optionally None)."""
    args = typing.get_args(hint)
    if type(None) in args:
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
    if hint is bool:
        if not isinstance(value, bool):
            raise f.error(where, f"must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise f.error(where, f"must be an integer, got {value!r}")
        return value
    if hint is float:
        return f.number(value, where)
    if typing.get_origin(hint) is tuple:
        return f.vector(value, where, len(typing.get_args(hint)))
    raise f.error(where, f"cannot be set from a file (type {hint})")


def _parse_section(f: _Fields, cls: type, base: Any, raw: Any, where: str) -> Any:
    raw = f.mapping(raw, where)
    hints = typing.get_type_hints(cls)
    names = {g.name for g in fields(cls)}
    f.only(raw, names, where)
    values = {k: _parse_value(f, v, hints[k], f"{where}.{k}" if where else k) for k, v in raw.items()}
    try:
        return replace(base, **values)
    except ValueError as exc:  # the dataclass's own checks name the field
        bad = next((k for k in values if re.search(rf"\.{k}\b", str(exc))), None)
        loc = ".".join(x for x in (where, bad) if x)
        raise f.error(loc, str(exc)) from None


def config_from_dict(data: Any, *, path: str | None = None, lines: dict[str, int] | None = None,
                     particles: int | None = None, base: str | None = None,
                     start: EstimatorConfig | None = None) -> EstimatorConfig:
    """An :class:`EstimatorConfig` from configuration data (a mapping of field names; sections as
    nested mappings): the fields given replace those of :func:`default_config` for the number of
    particles and the ``base`` named in the data, or of ``start`` when it is given. ``particles``
    and ``base`` given here take precedence over the data's. Raises
    :class:`~physics.errors.ConfigError` naming the file, line and field of a problem."""
    f = _Fields(path, lines or {}, ConfigError)
    data = dict({} if data is None else f.mapping(data, ""))
    base_name = data.pop("base", None)
    if base_name is not None and base_name not in BASES:
        raise f.error("base", f"must be one of {', '.join(BASES)}, got {base_name!r}")
    k = None
    if "particles" in data:
        k = _parse_value(f, data.pop("particles"), int, "particles")
        if k < 1:
            raise f.error("particles", f"must be >= 1, got {k}")
    k = particles if particles is not None else k
    if start is None:
        out = default_config(k or 1, base if base is not None else base_name)
    else:
        out = start if k is None else replace(start, particles=k)
    top = {name: v for name, v in data.items() if name not in SECTIONS}
    if top:
        out = _parse_section(f, EstimatorConfig, out, top, "")
    sections = {name: _parse_section(f, SECTIONS[name], getattr(out, name), data[name], name)
                for name in SECTIONS if name in data}
    return replace(out, **sections) if sections else out


def read_config_file(path: str | os.PathLike) -> tuple[Any, dict[str, int]]:
    """The data of a configuration file (YAML or JSON) and the line of each field."""
    return read_yaml_with_lines(path, "configuration file", ConfigError)


def load_config(path: str | os.PathLike, *, particles: int | None = None,
                base: str | None = None) -> EstimatorConfig:
    """Read a configuration file (see :func:`config_from_dict`)."""
    data, lines = read_config_file(path)
    return config_from_dict(data, path=str(path), lines=lines, particles=particles, base=base)
