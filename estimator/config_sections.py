"""The sections of the estimator's configuration (:class:`~estimator.config.EstimatorConfig`):
the physics reasoner's parameters (:class:`ReasonerConfig`, the paper's Table I), the particle
filter's perturbations and noise (:class:`NoiseConfig`; all zero is the paper's reasoner), how
tracked hands are read (:class:`HandConfig`), the adaptive particle count (:class:`AdaptiveConfig`)
and the live compute budget (:class:`BudgetConfig`). Frozen dataclasses with checked, documented
defaults; a configuration file names them ``reasoner:``, ``noise:``, ``hands:``, ``adaptive:`` and
``budget:``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


def check_positive(obj, *names):
    """Raises ``ValueError`` unless the fields ``names`` of ``obj`` are finite numbers above 0."""
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{type(obj).__name__}.{n} must be > 0, got {v!r}")


def check_flags(obj, *names):
    """Raises ``ValueError`` unless the fields ``names`` of ``obj`` are True or False."""
    for n in names:
        if not isinstance(getattr(obj, n), bool):
            raise ValueError(f"{type(obj).__name__}.{n} must be true or false, got {getattr(obj, n)!r}")


def check_counts(obj, lowest: int, *names):
    """Raises ``ValueError`` unless the fields ``names`` of ``obj`` are integers of at least ``lowest``."""
    for n in names:
        v = getattr(obj, n)
        if not isinstance(v, int) or isinstance(v, bool) or v < lowest:
            raise ValueError(f"{type(obj).__name__}.{n} must be an integer >= {lowest}, got {v!r}")


def check_nonneg(obj, *names):
    """Raises ``ValueError`` unless the fields ``names`` of ``obj`` are finite numbers of at least 0."""
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{type(obj).__name__}.{n} must be >= 0, got {v!r}")


RELEASE_DOWN_SPEED = 0.3
"""m/s: the acceleration clause of the Release rule (``ReasonerConfig.release_accel``) applies to
held objects perceived moving down at least this fast."""


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
      support's top (or inside a container), is put down (Place), unless it is more than
      ``push_lift`` above that support (held still above it: let go, it would drop and be held
      again). The paper leaves this rule implicit (see README).
    * ``release_speed`` (m/s) and ``release_accel`` (m/s^2): a held object perceived moving down
      faster than ``release_speed``, or accelerating down faster than ``release_accel`` (while moving
      down at :data:`RELEASE_DOWN_SPEED` or more) with nothing under it, was let go (Release, in view). Velocities are
      measured over the reasoning period. ``release_accel`` is fitted (``scene-estimator
      fit-priors --engines bullet,mujoco``, seeds 100-119 of every scenario with tracked hands under
      both truths, on the detections and on the Kalman tracker's filtered stream): the threshold that
      misclassifies the fewest of the perceived downward accelerations of held objects (hands
      lowering what they hold) and of objects just let go (44 of 2076 samples).
    * ``push_lift`` (m), ``push_smoothing`` and ``place_wait`` (s): a held object let go on a
      support whose height, smoothed over the updates (weight ``push_smoothing`` of the newest),
      never rose more than ``push_lift`` above where it rested before was pushed, not picked up: its
      Pick and Place are reported as one Push. A Place is dated when the object came to rest
      (``place_dwell`` before the rule fired) and waits (at most ``place_wait`` from then) for the
      object to rest where it was let go: if it is held again meanwhile, or falls more than
      ``push_lift`` below where it is perceived, it had not been put down (:mod:`actions.episodes`;
      not in the paper).
    * ``max_gap`` (s): an update simulates the stream time since the previous one, but at most this
      much: after a gap in the stream (a dropped connection, a paused recording) the scene is
      simulated for ``max_gap`` seconds, by which time what fell has landed and what rolls has
      mostly stopped, instead of for hours (an extension of the paper, which assumes a steady stream).
    """

    t_perceived: float = 0.7
    d_sim_perc: float = 0.045
    d_perc_prev: float = 0.032
    horizon: float = 0.08
    place_speed: float = 0.08
    place_spin: float = 1.0
    place_dwell: float = 0.3
    place_gap: float = 0.03
    release_speed: float = 1.0
    release_accel: float = 6.87
    max_gap: float = 2.0
    push_lift: float = 0.02
    push_smoothing: float = 0.3
    place_wait: float = 0.8

    def __post_init__(self):
        check_positive(self, "t_perceived", "d_sim_perc", "d_perc_prev", "place_speed", "place_gap",
                        "release_speed", "place_spin", "release_accel", "max_gap", "push_lift",
                        "push_smoothing")
        check_nonneg(self, "place_wait", "place_dwell", "horizon")
        if self.push_smoothing > 1:
            raise ValueError(f"ReasonerConfig.push_smoothing must be in (0, 1], got {self.push_smoothing!r}")


@dataclass(frozen=True)
class NoiseConfig:
    """Perturbations of the particle filter. All zeros (:meth:`off`) gives the paper's reasoner.

    * ``position_std`` (m) / ``orientation_std`` (rad): perception noise model, used both for
      initialising or overriding a particle's pose from perception and in the likelihood.
    * ``process_position_std`` (m per sqrt(s)) / ``process_orientation_std`` (rad per sqrt(s)):
      random-walk noise added to unperceived free objects at each update.
    * ``rest_speed`` (m/s): in a particle, an unperceived free object on a support and moving slower
      than this is at rest and gets no random walk: a resting object does not wander by itself (and,
      untouched, sleeps in its world, which makes resting scenes cheap to simulate).
    * ``fuse_resting`` / ``fusion_floor_std`` (m): perceived objects that rest, still, on a support
      take, in each particle, an ensemble Kalman step towards each detection (horizontal; prior
      variance the particles' weighted one plus ``fusion_floor_std**2``): a resting object is a
      static parameter of the filter, which resampling alone cannot move (:mod:`estimator.model.fusion`).
    * ``still_average``: where a perceived object seen still (no motion onset) is free, its divergence test's
      target and an override's pose are the average of its still detections, not the latest (``held_targets``).
    * ``motion_noise``: unperceived free objects resting on or in something also get position noise
      with a standard deviation of this fraction of the distance they moved in the last update
      (rolling and sliding are chaotic: the model error grows with motion; flight is not noised).
    * ``covariance_floor_std`` (m): added as ``std**2 * I`` to every reported position covariance,
      for what no particle represents (contact resolution, perception bias).
    * ``covariance_speed_time`` (s): an object not detected in an update also gets
      ``(covariance_speed_time * speed)**2 * I``, ``speed`` (m/s) being how fast its headline position
      moved over the update: what the particles share and the truth need not (a box jerked by a hand,
      a ball's roll) grows with how fast the object goes.
    * ``position_dof``: the reported position is a multivariate Student-t with this many degrees of
      freedom (> 2) and covariance ``position_cov`` (``None``: Gaussian). Its regions
      (:meth:`~estimator.belief.ObjectBelief.region`) are wider in the tails than a Gaussian's of the
      same covariance: the model's errors are not Gaussian (most hidden objects are within millimetres,
      a few are centimetres off).
      The three are fitted together on the simulator's scenarios, on seeds the evaluation does not use
      (``scene-estimator fit-priors --regions``), for 50 % and 90 % regions that hold what they say.
    * ``held_offset_std`` (m per axis) and ``held_offset_time`` (s): a held object that follows its
      tracked hand out of sight is at the hand plus the offset it had when last detected, plus an
      error per particle that grows from zero to this standard deviation with this time constant
      (the grasp slips, the hand turns: :func:`~estimator.worlds.held.hand_offset_walk`). The standard
      deviation is fitted on the simulator's scenarios (``scene-estimator fit-priors``).
    * ``held_drift_std`` (m per sqrt(s)): growth of the uncertainty of a held, unperceived object
      that has no tracked hand to follow.
    * ``friction_range``, ``rolling_friction_range``, ``spinning_friction_range``,
      ``restitution_range``, ``mass_scale_range``: uniform priors of the physical parameters, per
      object and particle (``None`` keeps the scene's value). Rolling and spinning friction are not
      perturbed by default: any rolling friction makes Bullet's contact solving much slower
      for resting boxes.
    * ``rolling_friction_scale`` (low, high): when ``rolling_friction_range`` is None, objects that
      can roll (spheres and cylinders) with a rolling friction in the scene get it multiplied, per
      particle, by a log-uniform factor in this range: a user rarely knows a ball's or a can's
      rolling friction within a factor of two, and it decides where a rolled object stops. Boxes
      keep theirs. None: not perturbed.
    * ``velocity_slack`` (m/s): an object seen moving along its support at two updates running is
      weighed on its perceived velocity against the velocity the particle's physics had given it
      (:class:`~estimator.model.mechanisms.velocity.VelocityTerm`: how fast a rolled ball slows down tells its
      rolling friction, which a teleport at every update hides from the position); this is added in
      quadrature to the perceived velocity's standard error. 0: not weighed.
    * ``decel_error``: an object seen rolling or sliding along its support, teleported in motion, is
      weighed on its deceleration, fitted through all its detections since it was first seen so (up to a second:
      :class:`~estimator.model.mechanisms.deceleration.DecelerationEvidence`), against the one each
      particle's physics gave it over its last update: this is what tells a ball's rolling friction,
      and where it will stop. ``decel_error`` is the physics' own error, a fraction of the perceived
      deceleration added in quadrature to the fit's standard error (two engines given the same
      stated rolling friction stop a rolled ball 5-10 % apart). 0: not weighed.
    * ``param_jitter``: after resampling, parameters are shrunk toward their weighted mean by
      ``a = sqrt(1 - jitter**2)`` and jittered so that their spread is kept (Liu & West; frictions
      and masses in log space, :mod:`estimator.model.params`); 0 disables.
    * ``param_floor``: the Liu-West kernel of a parameter the prior perturbs keeps at least this
      spread (log units: 0.1 is 10 %; linear for restitution), so that a resampling driven by
      something else does not fix a parameter for good before the evidence about it arrives.
    * ``param_widen``: the floor of the frictions' kernel (log units) of an object whose motion
      surprises every particle the same way (its perceived velocity consistently two standard deviations
      from theirs: :meth:`~estimator.model.mechanisms.velocity.VelocityEvidence.after_weighing`): the
      evidence says its friction is not where the particles have it; 0.35 is about a factor-two prior.
    * ``param_reach``: evidence may carry a parameter beyond its prior range by this factor (a
      friction prior of 0.3-1.0 bounds it to 0.075-4.0 with the default 4).
    * ``regularisation``: after resampling, hidden free objects are jittered with a Gaussian kernel
      of this bandwidth (under 1) times their weighted covariance (a regularised particle filter), each
      copy first drawn towards the cloud's mean so that the cloud keeps its spread (Liu-West); 0 disables.
    * ``max_jitter_std`` (m): cap of the motion noise and of the regularisation kernel per update,
      so that a jittered object does not jump through a container's wall.
    * ``outlier_prob``: weight of the uniform-outlier component of the pose likelihood (heavy tails).
    * ``miss_prob``: probability that the camera misses an object in plain view (negative evidence:
      a particle that puts an undetected object in view is weighted by it).
    * ``hand_radius`` (m): a tracked hand hides what is behind it from the camera, as a sphere of this
      radius at the tracked position (:func:`physics.visibility.sphere_occlusion`; the particle worlds
      do not contain hands): an adult hand's breadth across the knuckles is 8-9 cm (anthropometric
      surveys), a fist about as wide. 0: hands hide nothing.
    * ``hand_occlusion``: probability that the person hides an object their tracked hand *carries*
      (the hand has moved more than ``ModePriors.carry_distance`` since the object was last seen)
      with their body, which the particle worlds do not contain (a cup carried behind the back): a
      carried object in view pays ``log(hand_occlusion + (1 - hand_occlusion) * miss_prob)`` in all,
      not ``log(miss_prob)`` per update. A hand that has not moved since its object was last seen
      can hide it only with the hand itself (``hand_radius``): its object gets no such allowance,
      and one that vanishes from a still hand in plain view was let go. 1 exempts held objects from
      negative evidence. The default is fitted on the simulator's scenarios (``scene-estimator
      fit-priors``, seeds the evaluation does not use).
    """

    position_std: float = 0.01
    orientation_std: float = 0.2
    process_position_std: float = 0.003
    process_orientation_std: float = 0.01
    motion_noise: float = 0.3
    fuse_resting: bool = True
    still_average: bool = True
    fusion_floor_std: float = 0.001
    rest_speed: float = 0.01
    covariance_floor_std: float = 0.007  # fitted: scene-estimator fit-priors --regions (seeds 100-119)
    covariance_speed_time: float = 0.0  # fitted, as the floor
    position_dof: float | None = 3.0  # fitted, as the floor
    held_drift_std: float = 0.05
    held_offset_std: float = 0.0104  # fitted: fit-priors --engines bullet,mujoco (seeds 100-119)
    held_offset_time: float = 0.5
    friction_range: tuple[float, float] | None = (0.3, 1.0)
    rolling_friction_range: tuple[float, float] | None = None
    rolling_friction_scale: tuple[float, float] | None = (0.5, 2.0)
    spinning_friction_range: tuple[float, float] | None = None
    restitution_range: tuple[float, float] | None = (0.0, 0.3)
    mass_scale_range: tuple[float, float] | None = (0.8, 1.25)
    velocity_slack: float = 0.03
    decel_error: float = 0.1
    param_jitter: float = 0.1
    param_floor: float = 0.1
    param_widen: float = 0.35
    param_reach: float = 4.0
    regularisation: float = 0.5
    max_jitter_std: float = 0.01
    outlier_prob: float = 0.05
    miss_prob: float = 0.1
    hand_occlusion: float = 0.076  # fitted: fit-priors --engines bullet,mujoco (seeds 100-119), 2877 of 37725 frames
    hand_radius: float = 0.045

    def __post_init__(self):
        check_nonneg(self, "position_std", "orientation_std", "process_position_std", "process_orientation_std",
                     "held_drift_std", "held_offset_std", "param_jitter", "outlier_prob", "miss_prob", "motion_noise",
                     "rest_speed", "covariance_floor_std", "regularisation", "max_jitter_std", "fusion_floor_std",
                     "covariance_speed_time", "hand_radius", "param_floor", "velocity_slack", "param_widen",
                     "decel_error")
        check_flags(self, "fuse_resting", "still_average")
        if not (isinstance(self.param_reach, (int, float)) and self.param_reach >= 1):
            raise ValueError(f"NoiseConfig.param_reach must be >= 1, got {self.param_reach!r}")
        dof = self.position_dof
        if dof is not None and not (isinstance(dof, (int, float)) and math.isfinite(dof) and dof > 2):
            raise ValueError(f"NoiseConfig.position_dof must be > 2 (None: Gaussian), got {dof!r}")
        check_positive(self, "held_offset_time")
        if self.param_jitter >= 1 or self.regularisation >= 1:
            raise ValueError("NoiseConfig.param_jitter and regularisation (Liu-West bandwidths) must be < 1")
        if self.outlier_prob >= 1 or not 0 < self.miss_prob <= 1:
            raise ValueError("NoiseConfig.outlier_prob must be < 1 and miss_prob in (0, 1]")
        if not (isinstance(self.hand_occlusion, (int, float)) and 0.0 <= self.hand_occlusion <= 1.0):
            raise ValueError(f"NoiseConfig.hand_occlusion must be in [0, 1], got {self.hand_occlusion!r}")
        for n in ("friction_range", "rolling_friction_range", "spinning_friction_range",
                  "restitution_range", "mass_scale_range"):
            r = getattr(self, n)
            if r is not None and not (len(r) == 2 and 0 <= r[0] <= r[1] and math.isfinite(r[1])):
                raise ValueError(f"NoiseConfig.{n} must be (low, high) with 0 <= low <= high, got {r!r}")
        r = self.rolling_friction_scale
        if r is not None and not (len(r) == 2 and 0 < r[0] <= r[1] and math.isfinite(r[1])):
            raise ValueError(f"NoiseConfig.rolling_friction_scale must be (low, high) with 0 < low <= high, got {r!r}")
        if self.mass_scale_range is not None and self.mass_scale_range[0] <= 0:
            raise ValueError("NoiseConfig.mass_scale_range must be positive")

    @classmethod
    def off(cls) -> "NoiseConfig":
        """No perturbation at all: the paper's deterministic reasoner."""
        return cls(position_std=0.0, orientation_std=0.0, process_position_std=0.0, process_orientation_std=0.0,
                   motion_noise=0.0, covariance_floor_std=0.0, covariance_speed_time=0.0, position_dof=None,
                   held_drift_std=0.0, held_offset_std=0.0, friction_range=None, rolling_friction_range=None,
                   rolling_friction_scale=None, spinning_friction_range=None, restitution_range=None,
                   mass_scale_range=None, param_jitter=0.0, regularisation=0.0, outlier_prob=0.0,
                   miss_prob=0.1, hand_occlusion=1.0, fuse_resting=False, still_average=False)

    @property
    def is_off(self) -> bool:
        return self == NoiseConfig.off()


@dataclass(frozen=True)
class HandConfig:
    """How the positions of tracked hands, and the offsets of held objects to them, are read
    (:mod:`estimator.model.hands`). A tracked hand (a skeleton tracker's wrist) is noisier than an
    object's detection; the object a hand carries out of view is put at the hand plus its offset,
    so both errors become the hidden object's.

    * ``measurement_std`` (m per axis): noise of a tracked hand's position; fitted on the
      simulator's scenarios (``scene-estimator fit-priors``: tracked minus true hand, RMS per axis).
    * ``accel_std`` (m/s^2): white acceleration of each hand's constant-velocity Kalman filter;
      the 99th percentile of held objects' accelerations in the scenarios, as the pose tracker's
      (:attr:`~estimator.applications.tracker.TrackerConfig.accel_std`): a hand moves what it holds.
    * ``restart_gap`` (s): a hand not tracked for longer than this starts again at its next position, at rest.
    * ``offset_time`` (s): a held object's offset to its hand is the exponential average of
      (detection - tracked hand) over the frames that show both, each new frame weighing
      ``max(1 / n, 1 - exp(-dt / offset_time))`` (``n`` frames so far, ``dt`` since the last): the
      grasp is steady over this long.
    * ``offset_gate`` (m): a frame whose difference lies farther than this from the average starts
      the average again (a new grasp, or a hand passing by an object it does not hold).
    * ``filtered``: False reads each hand's latest raw position and each offset from the latest
      frame alone (the estimator before hands were filtered).
    """

    measurement_std: float = 0.01  # fitted: scene-estimator fit-priors (seeds 100-119)
    accel_std: float = 5.0
    restart_gap: float = 0.5
    offset_time: float = 0.5
    offset_gate: float = 0.04
    filtered: bool = True

    def __post_init__(self):
        check_positive(self, "measurement_std", "accel_std", "restart_gap", "offset_time", "offset_gate")
        check_flags(self, "filtered")


@dataclass(frozen=True)
class AdaptiveConfig:
    """A particle count that follows the belief's spread: KLD-sampling (Fox, 2003), per object.

    At every update each known dynamic object's particles are put in bins: a cube of ``bin_size``
    (m) centred on the object's weighted mean position (an object whose spread is under half a bin
    fills one bin, wherever it stands), one set of bins per mode (free, held). A bin counts when its
    weight is at least half a particle's share (``1 / (2 K)``). With ``k`` bins counted, Fox's bound

        n(k) = (k - 1) / (2 epsilon) * (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1))) * z)^3

    (``z`` the standard normal quantile of ``1 - delta``; the Wilson-Hilferty approximation of the
    chi-square quantile) is the number of samples that keeps the Kullback-Leibler divergence between
    that object's binned marginal and its sample estimate under ``epsilon`` with probability ``1 -
    delta``. The filter needs the largest ``n`` over the objects, clipped to ``[min_particles,
    max_particles]``: a joint bound over every object would count the product of their bins. The
    orientation and the physical parameters are not binned.

    The filter resamples to that count when its effective sample size falls under the threshold or
    the count under ``shrink_below`` times K (all seen, at rest); a count over K (a vanished object, a
    split) adds weighed copies instead (:func:`~estimator.resampling.split_ancestors`).

    * ``enabled``: False keeps K fixed at ``EstimatorConfig.particles`` (the default).
    * ``min_particles``, ``max_particles``: bounds on K (the worlds are built for the maximum as K
      first reaches it, and parked, not destroyed, when K falls). The minimum is the least K whose
      50 % and 90 % regions fitted to K samples of a Gaussian cover on average within one point of
      their level (:func:`~estimator.adaptive.coverage_min_particles`; a fitted 90 % region covers
      0.875 at K = 64, 0.890 at 164): an object's cloud in one bin is estimated from its particles, and
      a vanished object's grows out of them (docs/concepts/adaptive-particles.md).
    * ``epsilon``, ``delta``, ``bin_size`` (m), ``shrink_below``: as above.
    """

    enabled: bool = False
    min_particles: int = 164  # coverage_min_particles()
    max_particles: int = 1024
    epsilon: float = 0.05
    delta: float = 0.01
    bin_size: float = 0.05
    shrink_below: float = 0.5

    def __post_init__(self):
        check_flags(self, "enabled")
        check_counts(self, 2, "max_particles", "min_particles")
        if self.max_particles < self.min_particles:
            raise ValueError(f"AdaptiveConfig.max_particles ({self.max_particles}) must be >= min_particles "
                             f"({self.min_particles})")
        check_positive(self, "epsilon", "bin_size")
        for n in ("delta", "shrink_below"):
            v = getattr(self, n)
            if not 0.0 < v < 1.0:
                raise ValueError(f"AdaptiveConfig.{n} must be in (0, 1), got {v!r}")


@dataclass(frozen=True)
class BudgetConfig:
    """A compute budget for live use (``run --live``, ``ros``): the particle count is capped so that
    the reasoning steps keep up with the stream.

    After each reasoning step the filter compares the wall time the step took with ``load`` times the
    stream time it covered (the time it simulated, at least one horizon): the *budget*. A step over
    it lowers the cap to the count the budget affords (the particle worlds' time scaling with K, the
    rest taken as fixed), to no fewer than ``min_particles``; one under ``slack`` times the budget
    raises it by at most the factor ``grow`` per step, up to the count configured (``particles``, or
    ``adaptive.max_particles``); in between it stays (:func:`~estimator.config.budget_cap`). The
    filter resamples to the cap as soon as it holds more particles, and back up when the cap allows
    its count again. K then depends on the machine's speed and load: a run with a budget is not
    reproducible, as a live run's merged frames are not.

    * ``enabled``: False (the default) keeps K to what ``particles`` and ``adaptive`` say.
    * ``min_particles``: the fewest particles the budget leaves (16: the Monte Carlo error of a
      well-known object's mean position grows by ``sqrt(1 + 1/16)``, 3 %; below, frames are merged).
    * ``load``: the fraction of the stream's time the steps may take (the rest observes frames and
      writes estimates); ``slack``, ``grow``: as above.
    """

    enabled: bool = False
    min_particles: int = 16
    load: float = 0.8
    slack: float = 0.6
    grow: float = 1.25

    def __post_init__(self):
        check_flags(self, "enabled")
        check_counts(self, 2, "min_particles")
        if not 0.0 < self.load <= 1.0:
            raise ValueError(f"BudgetConfig.load must be in (0, 1], got {self.load!r}")
        if not 0.0 < self.slack < 1.0:
            raise ValueError(f"BudgetConfig.slack must be in (0, 1), got {self.slack!r}")
        if not self.grow > 1.0:
            raise ValueError(f"BudgetConfig.grow must be > 1, got {self.grow!r}")
