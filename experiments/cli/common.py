"""What the subcommands share: the estimator options, the configuration they build, the summary
they print."""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from estimator.config import (
    AdaptiveConfig,
    BudgetConfig,
    EstimatorConfig,
    ReasonerConfig,
    config_from_dict,
    default_config,
    read_config_file,
    with_adaptive_count,
    with_budget,
)

DEFAULT_PARTICLES = 64
"""Particle worlds K of ``run``, ``config``, ``track --feedback`` and ``demo`` when neither the
command line (``--particles``, ``--paper``) nor a configuration file says: every built-in scenario
runs in real time at K = 64 on two cores (README, *Speed*)."""

AUTO_DEFAULTS = AdaptiveConfig()
"""``--particles auto``'s default bounds, for the commands' help."""
AUTO_RANGE = f"{AUTO_DEFAULTS.min_particles}-{AUTO_DEFAULTS.max_particles}"


def particle_count(text: str) -> int | str:
    """``--particles``: a positive integer, or ``auto`` (a count that follows the belief's spread)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        k = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'auto', got {text!r}") from None
    if k < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'auto', got {text!r}")
    return k


def _particles(args, file_data) -> int | None:
    """K asked for: ``--paper`` is 1, else ``--particles``; ``None`` when a configuration file
    decides (it names ``particles`` or ``base: paper``); else :data:`DEFAULT_PARTICLES`."""
    if getattr(args, "paper", False):
        if args.particles not in (None, 1) or args.noise:
            raise ValueError("--paper is one world without noise: drop --particles / --noise")
        return 1
    if args.particles == "auto":
        return DEFAULT_PARTICLES  # where the adaptive count starts
    if args.particles is not None:
        return args.particles
    if isinstance(file_data, dict) and ("particles" in file_data or file_data.get("base") == "paper"):
        return None
    return DEFAULT_PARTICLES


def build_config(args) -> EstimatorConfig:
    """Estimator configuration from ``run`` arguments. Without ``--config``, the particle filter
    with :data:`DEFAULT_PARTICLES` worlds and its default noise; ``--paper`` (or ``--particles 1``)
    is the paper's reasoner unless ``--noise`` is given; more particles use the default noise unless
    ``--no-noise``. A configuration file (``--config``) changes the fields it names; options given
    on the command line win over the file."""
    paper = getattr(args, "paper", False)
    base = "particles" if args.noise else ("paper" if args.no_noise or paper else None)
    file_data = None
    if args.config:
        file_data, lines = read_config_file(args.config)
        cfg = config_from_dict(file_data, path=args.config, lines=lines, particles=_particles(args, file_data),
                               base=base)
    else:
        cfg = default_config(_particles(args, None), base)
    lo, hi = getattr(args, "min_particles", None), getattr(args, "max_particles", None)
    if getattr(args, "particles", None) == "auto" or lo is not None or hi is not None:
        if args.particles not in ("auto", None):
            raise ValueError("--min-particles / --max-particles go with --particles auto")
        cfg = with_adaptive_count(cfg, lo, hi)
    given = {name: getattr(args, name) for name in ("horizon", "t_perceived", "d_sim_perc", "d_perc_prev")
             if getattr(args, name) is not None}
    if given:
        cfg = dataclasses.replace(cfg, reasoner=dataclasses.replace(cfg.reasoner, **given))
    workers = args.workers
    if workers is None and not (isinstance(file_data, dict) and "workers" in file_data):
        workers = (os.cpu_count() or 1) if cfg.particles > 1 else 0
    if workers is not None:
        cfg = dataclasses.replace(cfg, workers=workers)
    args.workers = cfg.workers
    return cfg


def add_estimator_arguments(p: argparse.ArgumentParser) -> None:
    """The options that choose and configure the estimator (``run``, ``config``, ``track``, ``search``)."""
    d = ReasonerConfig()
    p.add_argument("--config", metavar="FILE",
                   help="estimator configuration file (YAML or JSON): the fields to change, e.g. "
                        "'noise: {position_std: 0.02}'; `scene-estimator config` prints them all")
    p.add_argument("--particles", type=particle_count, default=None,
                   help=f"particle worlds K (default {DEFAULT_PARTICLES}, or the configuration file's; "
                        "1: the paper's reasoner; auto: a count that follows the belief's spread, "
                        f"KLD-sampling, {AUTO_RANGE}, starting at the fewest)")
    p.add_argument("--max-particles", type=int, default=None,
                   help=f"with --particles auto: the most particles (default {AUTO_DEFAULTS.max_particles})")
    p.add_argument("--min-particles", type=int, default=None,
                   help=f"with --particles auto: the fewest particles (default {AUTO_DEFAULTS.min_particles})")
    p.add_argument("--paper", action="store_true",
                   help="the paper's reasoner: one world, no noise (same as --particles 1)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes holding the particle worlds (0: in this process; "
                        "default: one per core when there is more than one particle)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--noise", action="store_true", help="perturb even with one particle")
    p.add_argument("--no-noise", action="store_true", help="no perturbation even with many particles")
    p.add_argument("--horizon", type=float, default=None, help=f"reasoning period in s ({d.horizon})")
    p.add_argument("--t-perceived", type=float, default=None, help=f"perceived timeout in s ({d.t_perceived})")
    p.add_argument("--d-sim-perc", type=float, default=None, help=f"simulation tolerance in m ({d.d_sim_perc})")
    p.add_argument("--d-perc-prev", type=float, default=None, help=f"perception jump in m ({d.d_perc_prev})")


def add_fixed_particles_argument(p: argparse.ArgumentParser, always_live: bool = False) -> None:
    """``--fixed-particles`` (``run``, ``ros``, ``bench``): keep K fixed in a live run. The help
    states the budget's defaults (:class:`~estimator.config.BudgetConfig`)."""
    b = BudgetConfig()
    p.add_argument("--fixed-particles", action="store_true", default=None,
                   help=f"keep the particle count fixed: by default {'the node' if always_live else 'a live run'} "
                        f"sheds particles while its reasoning steps take more than {100 * b.load:.0f} %% of the "
                        f"stream time they cover (down to {b.min_particles}, the configuration's "
                        f"budget.min_particles) and takes them back once they take under "
                        f"{100 * b.slack * b.load:.0f} %%; frames that arrive during a step are merged either way")


def live_config(config: EstimatorConfig, live: bool, fixed_particles: bool | None) -> EstimatorConfig:
    """A run's configuration for ``--live`` / ``--fixed-particles``: live, the compute budget on
    (:class:`~estimator.config.BudgetConfig`) unless ``fixed_particles``, or unless it could not
    change K (the paper's reasoner, K at most the budget's floor); not live, ``config`` as it is.
    ``--fixed-particles`` without ``--live`` is a ``ValueError``."""
    if fixed_particles and not live:
        raise ValueError("--fixed-particles goes with --live (only a live run sheds particles)")
    if not live or fixed_particles or config.max_particles <= config.budget.min_particles:
        return config
    return with_budget(config)


def print_summary(summary: dict, stream=None) -> None:
    """A readable timeline and the final poses."""
    stream = stream or sys.stdout
    tl = summary["timeline"]
    print(f"{summary['frames']} frames read, {summary['skipped']} skipped, {summary['estimates']} "
          f"reasoning steps in {summary['seconds']:.2f} s", file=stream)
    if summary.get("particles"):
        k = summary["particles"]
        why = " and ".join(w for w in ("adaptive", "budget") if k[w])
        print(f"particles ({why}): {k['min']} to {k['max']}, {k['mean']:.0f} on average", file=stream)
    if summary.get("rejected"):
        print(f"{summary['rejected']} detection(s) outside the scene's workspace rejected as outliers", file=stream)
    if summary.get("reseeded") or summary.get("worker_restarts"):
        print(f"{summary.get('reseeded', 0)} particle(s) re-seeded from the others after an exploded simulation "
              f"or a dead worker; {summary.get('worker_restarts', 0)} worker restart(s)", file=stream)
    print("\nEvents:", file=stream)
    for e in tl["events"]:
        print(f"  t={e['t']:7.3f}  {e['action']:<8} {e['subject']:<14} p={e['p']:.2f}", file=stream)
    if not tl["events"]:
        print("  (none)", file=stream)
    print("\nFacts:", file=stream)
    for f in tl["facts"]:
        if f["predicate"] == "isPerceived":
            continue
        rel = f"{f['predicate']}({f['subject']}" + (f", {f['object']})" if f["object"] else ")")
        end = "..." if f["end"] is None else f"{f['end']:.3f}"
        print(f"  {rel:<36} {f['start']:7.3f} -> {end:<8} confidence {f['confidence']:.2f}", file=stream)
    b = summary["last_belief"]
    if b is not None:
        print(f"\nFinal poses (t={b.t:.3f} s):", file=stream)
        for oid, ob in b.objects.items():
            pos = ", ".join(f"{v:+.3f}" for v in ob.position)
            where = ", ".join(f"{h.relation} {h.support or ''}".strip() + f" {h.p:.2f}" for h in ob.hypotheses)
            seen = "perceived" if ob.perceived else "hidden   "
            if not ob.hypotheses and ob.p_held == 0 and not ob.perceived:
                seen = "static   "
            print(f"  {oid:<14} [{pos}]  {seen}  {where}", file=stream)
