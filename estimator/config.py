"""Configuration of the estimator: frozen dataclasses with checked, documented defaults.

:class:`ReasonerConfig` holds the parameters of the IROS 2019 physics reasoner (its Table I).
:class:`NoiseConfig` the perturbations of the particle filter; all zero is the paper's reasoner.
:class:`EstimatorConfig` bundles them with the particle count, resampling and output settings.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from actions.modes import ModePriors
from physics.world import PhysicsSettings

from .relations import RelationConfig


def _check_positive(obj, *names):
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{type(obj).__name__}.{n} must be > 0, got {v!r}")


def _check_nonneg(obj, *names):
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{type(obj).__name__}.{n} must be >= 0, got {v!r}")


@dataclass(frozen=True)
class ReasonerConfig:
    """The physics reasoner's parameters (defaults: Table I of Sallami et al., IROS 2019).

    * ``t_perceived`` (s): an object seen within this time counts as perceived.
    * ``d_sim_perc`` (m): a perceived free object whose simulation diverges from its perceived
      position by more than this, at any simulation step, is not physically plausible.
    * ``d_perc_prev`` (m): a perceived position that jumps by more than this since the previous
      update teleports the object (and its contents) to the perception.
    * ``horizon`` (s): the reasoning period: an update runs when the stream's time has advanced by
      at least ``horizon`` since the last one, and simulates exactly the elapsed time. 0 reasons at
      every frame.
    * ``place_speed`` (m/s), ``place_spin`` (rad/s), ``place_dwell`` (s) and ``place_gap`` (m): a
      held object whose detections over the last ``place_dwell`` moved slower than ``place_speed``
      and turned slower than ``place_spin`` on average, with its bottom within ``place_gap`` of a
      support's top (or inside a container), is put down (Place). The paper leaves this rule
      implicit (see README).
    * ``release_speed`` (m/s) and ``release_accel`` (m/s^2): a held object perceived moving down
      faster than ``release_speed``, or accelerating down faster than ``release_accel`` (while moving
      down at 0.3 m/s or more) with nothing under it, was let go (Release, in view). Velocities are
      measured over the reasoning period.
    """

    t_perceived: float = 0.7
    d_sim_perc: float = 0.045
    d_perc_prev: float = 0.032
    horizon: float = 0.08
    place_speed: float = 0.15
    place_spin: float = 1.0
    place_dwell: float = 0.3
    place_gap: float = 0.03
    release_speed: float = 1.0
    release_accel: float = 4.0

    def __post_init__(self):
        _check_positive(self, "t_perceived", "d_sim_perc", "d_perc_prev", "place_speed", "place_gap",
                        "release_speed", "place_spin", "release_accel")
        _check_nonneg(self, "place_dwell")
        _check_nonneg(self, "horizon")


@dataclass(frozen=True)
class NoiseConfig:
    """Perturbations of the particle filter. All zeros (:meth:`off`) gives the paper's reasoner.

    * ``position_std`` (m) / ``orientation_std`` (rad): perception noise model, used both for
      initialising or overriding a particle's pose from perception and in the likelihood.
    * ``process_position_std`` (m per sqrt(s)) / ``process_orientation_std`` (rad per sqrt(s)):
      random-walk noise added to unperceived free objects at each update.
    * ``motion_noise``: unperceived free objects resting on or in something also get position noise
      with a standard deviation of this fraction of the distance they moved in the last update
      (rolling and sliding are chaotic: the model error grows with motion; flight is not noised).
    * ``covariance_floor_std`` (m): added as ``std**2 * I`` to every reported position covariance,
      for what no particle represents (contact resolution, perception bias).
    * ``held_drift_std`` (m per sqrt(s)): growth of the uncertainty of a held, unperceived object
      that has no tracked hand to follow.
    * ``friction_range``, ``rolling_friction_range``, ``spinning_friction_range``,
      ``restitution_range``, ``mass_scale_range``: uniform priors of the physical parameters, per
      object and particle (``None`` keeps the scene's value). Rolling and spinning friction are not
      perturbed by default: any rolling friction makes Bullet's contact solving several times slower
      for resting boxes.
    * ``param_jitter``: after resampling, parameters are shrunk toward their weighted mean by
      ``a = sqrt(1 - jitter**2)`` and jittered so that their spread is kept (Liu & West); 0 disables.
    * ``regularisation``: after resampling, hidden free objects are jittered with a Gaussian kernel
      of this bandwidth times their weighted covariance (a regularised particle filter); 0 disables.
    * ``max_jitter_std`` (m): cap of the motion noise and of the regularisation kernel per update,
      so that a jittered object does not jump through a container's wall.
    * ``outlier_prob``: weight of the uniform-outlier component of the pose likelihood (heavy tails).
    * ``miss_prob``: probability that the camera misses an object in plain view (negative evidence:
      a particle that puts an undetected object in view is weighted by it).
    """

    position_std: float = 0.01
    orientation_std: float = 0.2
    process_position_std: float = 0.003
    process_orientation_std: float = 0.01
    motion_noise: float = 0.3
    covariance_floor_std: float = 0.005
    held_drift_std: float = 0.05
    friction_range: tuple[float, float] | None = (0.3, 1.0)
    rolling_friction_range: tuple[float, float] | None = None
    spinning_friction_range: tuple[float, float] | None = None
    restitution_range: tuple[float, float] | None = (0.0, 0.3)
    mass_scale_range: tuple[float, float] | None = (0.8, 1.25)
    param_jitter: float = 0.1
    regularisation: float = 0.5
    max_jitter_std: float = 0.01
    outlier_prob: float = 0.05
    miss_prob: float = 0.1

    def __post_init__(self):
        _check_nonneg(self, "position_std", "orientation_std", "process_position_std",
                      "process_orientation_std", "held_drift_std", "param_jitter", "outlier_prob", "miss_prob",
                      "motion_noise", "covariance_floor_std", "regularisation", "max_jitter_std")
        if self.param_jitter >= 1:
            raise ValueError("NoiseConfig.param_jitter must be < 1")
        if self.outlier_prob >= 1 or not 0 < self.miss_prob <= 1:
            raise ValueError("NoiseConfig.outlier_prob must be < 1 and miss_prob in (0, 1]")
        for n in ("friction_range", "rolling_friction_range", "spinning_friction_range",
                  "restitution_range", "mass_scale_range"):
            r = getattr(self, n)
            if r is not None and not (len(r) == 2 and 0 <= r[0] <= r[1] and math.isfinite(r[1])):
                raise ValueError(f"NoiseConfig.{n} must be (low, high) with 0 <= low <= high, got {r!r}")
        if self.mass_scale_range is not None and self.mass_scale_range[0] <= 0:
            raise ValueError("NoiseConfig.mass_scale_range must be positive")

    @classmethod
    def off(cls) -> "NoiseConfig":
        """No perturbation at all: the paper's deterministic reasoner."""
        return cls(position_std=0.0, orientation_std=0.0, process_position_std=0.0,
                   process_orientation_std=0.0, motion_noise=0.0, covariance_floor_std=0.0,
                   held_drift_std=0.0, friction_range=None,
                   rolling_friction_range=None, spinning_friction_range=None, restitution_range=None,
                   mass_scale_range=None, param_jitter=0.0, regularisation=0.0, outlier_prob=0.0,
                   miss_prob=0.1)

    @property
    def is_off(self) -> bool:
        return self == NoiseConfig.off()


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything the estimator needs besides the scene.

    * ``particles``: number of particle worlds K (1 with :meth:`NoiseConfig.off` is paper mode).
    * ``workers``: worker processes holding the particle worlds (0 = in this process; results do
      not depend on it).
    * ``resample_threshold``: resample when the effective sample size falls below this fraction of K.
    * ``event_threshold``: an event enters the timeline when its probability exceeds this.
    * ``event_window`` (s): an event's probability is the weight of the particles that made that
      switch within this window (particles carry their event times through resampling).
    * ``negative_evidence``: particles that put an unperceived object in plain view of the camera
      lose weight (needs a camera in the scene).
    * ``follow_hands``: a held object that is not detected follows the tracked hand nearest to it
      when last detected (the paper's reasoner ignores hands: off in paper mode).
    * ``lazy_checks``: test an object's divergence only when it could have crossed the threshold
      since the last test (see :func:`~estimator.propagate.propagate`); off in paper mode, which
      tests after every step. Reading poses back is most of the estimator's cost over bare stepping.
    * ``fresh_checks``: only objects detected since the previous update are tested for divergence
      (a released object is not pulled back to where it was last seen); the paper tests every object
      seen within ``t_perceived`` (off in paper mode).
    * ``physics``: the particle worlds' engine settings; the solver stops at a residual of 1e-4
      (the ground-truth simulator keeps pybullet's 1e-7): resting scenes step faster.
    * ``visibility_threshold``: fraction of an object's sample points in view for it to count as
      visible to the camera.
    """

    particles: int = 1
    workers: int = 0
    reasoner: ReasonerConfig = field(default_factory=ReasonerConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig.off)
    priors: ModePriors = field(default_factory=ModePriors)
    relations: RelationConfig = field(default_factory=RelationConfig)
    physics: PhysicsSettings = field(default_factory=lambda: PhysicsSettings(solver_residual_threshold=1e-4))
    resample_threshold: float = 0.5
    event_threshold: float = 0.5
    event_window: float = 1.0
    negative_evidence: bool = True
    follow_hands: bool = True
    lazy_checks: bool = True
    fresh_checks: bool = True
    visibility_threshold: float = 0.3
    hypothesis_min_p: float = 0.02

    def __post_init__(self):
        if not isinstance(self.particles, int) or self.particles < 1:
            raise ValueError(f"EstimatorConfig.particles must be an integer >= 1, got {self.particles!r}")
        if not isinstance(self.workers, int) or self.workers < 0:
            raise ValueError(f"EstimatorConfig.workers must be an integer >= 0, got {self.workers!r}")
        if not self.event_window > 0:
            raise ValueError(f"EstimatorConfig.event_window must be > 0, got {self.event_window!r}")
        for n in ("resample_threshold", "event_threshold", "visibility_threshold",
                  "hypothesis_min_p"):
            v = getattr(self, n)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"EstimatorConfig.{n} must be in [0, 1], got {v!r}")

    @property
    def paper_mode(self) -> bool:
        """True when this configuration is the paper's reasoner (one world, no noise)."""
        return self.particles == 1 and self.noise.is_off and self.priors.release_on_loss == 1.0

    @classmethod
    def paper(cls, reasoner: ReasonerConfig | None = None) -> "EstimatorConfig":
        """The single-world, noise-free physics reasoner of Sallami et al. (2019)."""
        return cls(particles=1, noise=NoiseConfig.off(), reasoner=reasoner or ReasonerConfig(),
                   priors=ModePriors(release_on_loss=1.0), negative_evidence=False, follow_hands=False,
                   lazy_checks=False, fresh_checks=False)
