"""``scene-estimator fit-priors``: the held-object priors fitted on simulated scenarios
(:func:`experiments.evaluation.fit_priors.fit_priors`), or with ``--regions`` the reported position
distribution (:func:`experiments.evaluation.fit_regions.fit_regions`), printed as JSON."""
from __future__ import annotations

import argparse
import json
import os
import shutil

from estimator.config import load_config
from experiments.evaluation.fit_priors import FIT_SEEDS, fit_priors
from experiments.evaluation.fit_regions import RegionSamples, collect_region_samples, fit_regions, region_config


def seed_range(text: str) -> range:
    """``FIRST-LAST`` (or one seed) as a range; a clear error otherwise."""
    try:
        lo, _, hi = text.partition("-")
        out = range(int(lo), int(hi or lo) + 1)
    except ValueError:
        raise ValueError(f"--seeds: expected FIRST-LAST (e.g. 100-119), got {text!r}") from None
    if len(out) == 0:
        raise ValueError(f"--seeds: empty range {text!r}")
    return out


def add_fit_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``fit-priors``."""
    p.add_argument("--seeds", default=f"{FIT_SEEDS.start}-{FIT_SEEDS.stop - 1}",
                   help="seed range FIRST-LAST (default 100-119: the evaluation uses 0-19)")
    p.add_argument("--scenarios", default="all",
                   help="'all' (every built-in scenario with tracked hands; with --regions, every one) or "
                        "comma-separated names")
    p.add_argument("--engines", default="bullet", metavar="ENGINE[,ENGINE]",
                   help="truth engines whose runs the priors are fitted on together (bullet, mujoco, or "
                        "bullet,mujoco: then also the fit on each alone and its held-out log-likelihood on the "
                        "other's runs) (default bullet); not with --regions")
    p.add_argument("--regions", action="store_true",
                   help="fit the position regions instead (covariance floor, speed term, Student-t degrees of "
                        "freedom): runs the particle estimator on every scenario x seed")
    p.add_argument("--particles", type=int, default=64, help="particles of the --regions runs (default 64)")
    p.add_argument("--workers", type=int, default=1, help="processes of the --regions runs (default 1)")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="estimator configuration file (YAML or JSON) whose reasoner, priors and hands the priors fit "
                        "replays (default: the particle filter's defaults); not with --regions")
    p.add_argument("--samples", default=None,
                   help="with --regions: an .npz of the collected samples; read if it exists (no runs: re-fit "
                        "only), else written once collected (each trial's samples go to FILE.parts/ as it "
                        "ends: an interrupted collection resumes from them)")


def run_fit(args) -> int:
    names = None if args.scenarios == "all" else [s.strip() for s in args.scenarios.split(",") if s.strip()]
    if args.regions and args.config:
        raise ValueError("--config: the regions fit runs the estimator's defaults; use --config without --regions")
    if args.regions:
        if args.particles < 1 or args.workers < 1:
            raise ValueError(f"--particles and --workers must be >= 1, got {args.particles}, {args.workers}")
        cached = args.samples
        loaded = bool(cached) and os.path.exists(cached)
        if loaded:
            samples = RegionSamples.load(cached)
        else:
            parts = cached + ".parts" if cached else None  # each trial's samples, kept if interrupted
            samples = collect_region_samples(names, seed_range(args.seeds), args.particles, args.workers, parts)
            if cached:
                samples.save(cached)
                shutil.rmtree(parts, ignore_errors=True)
        fit = fit_regions(samples)
        fit.update(config=region_config(fit), scenarios=list(samples.scenarios))
        if loaded:
            fit.update(samples_file=cached)  # collected by an earlier run: its seeds and K are that run's
        else:
            fit.update(seeds=[int(s) for s in seed_range(args.seeds)], particles=args.particles)
        print(json.dumps(fit, indent=1))
        return 0
    from experiments.simulation.simulator import ENGINES
    text = getattr(args, "engines", "bullet")
    engines = tuple(e.strip() for e in text.split(",") if e.strip())
    if not engines or any(e not in ENGINES for e in engines):
        raise ValueError(f"--engines: expected engines among {', '.join(ENGINES)}, got {text!r}")
    config = load_config(args.config) if args.config else None
    print(json.dumps(fit_priors(names, seed_range(args.seeds), config, engines), indent=1))
    return 0
