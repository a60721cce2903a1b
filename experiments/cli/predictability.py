"""``scene-estimator predictability``: which scenarios let anyone say where their objects end, to
5 cm: each (scenario, seed) of the evaluation run again as twins that differ from the truth by what
the robot could not know (each object moved by the tracker's noise at its last sighting, the
physical parameters the scenario randomises drawn again;
:mod:`experiments.evaluation.predictability`); with ``--evaluation DIR``, each method's success
beside it and pooled over the predictable scenarios.

    scene-estimator predictability --seeds 20 --workers 2 --out results/ --evaluation results/

Interrupted, the same command continues where it stopped (``OUT/twins.jsonl``)."""
from __future__ import annotations

import argparse
import os
import sys


def add_predictability_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``predictability``."""
    from experiments.evaluation.predictability import AT, PARAMS, TwinConfig

    d = TwinConfig()
    p.add_argument("--scenarios", default="all", help="'all' or comma-separated scenario names (default all)")
    p.add_argument("--seeds", type=int, default=20, help="seeds 0 .. N-1, the evaluation's (default 20)")
    p.add_argument("--twins", type=int, default=d.twins, help=f"twins per scenario and seed (default {d.twins})")
    p.add_argument("--at", choices=AT, default=d.at,
                   help="perturb each object at its last sighting (default) or every object at the start")
    p.add_argument("--position-std", type=float, default=d.position_std,
                   help="std (m) per axis of the perturbation (default: the scenario's tracker noise, its "
                        "position_std, and hand_std for an object in the hand)")
    p.add_argument("--params", choices=PARAMS, default=d.params,
                   help="'scenario' (default): the physical parameters the scenario randomises are drawn again "
                        "from its ranges (the estimator is told the nominal ones); 'scale': the truth's")
    p.add_argument("--param-scale", type=float, default=d.param_scale,
                   help=f"twins' physical parameters x U(1 - s, 1 + s) from the start (default {d.param_scale:g})")
    p.add_argument("--threshold", type=float, default=d.threshold,
                   help=f"an object's agreement below which its scenario is unpredictable to 5 cm "
                        f"(default {d.threshold:g})")
    p.add_argument("--engine", choices=("bullet", "mujoco"), default=d.engine,
                   help="physics engine of the truth and its twins (default bullet); with --evaluation, only "
                        "that engine's trials (unscaled parameters) are set beside the agreement")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1); results do not depend on it")
    p.add_argument("--out", default="results", help="output folder: twins.jsonl, predictability.md/.csv")
    p.add_argument("--evaluation", default=None,
                   help="an evaluate output folder (its trials.jsonl): methods' success beside the agreement")
    p.add_argument("--quiet", action="store_true", help="no progress, no report on stdout")


def run_predictability(args) -> int:
    from experiments.evaluation.predictability import TwinConfig, run_twins
    from experiments.evaluation.predictability_report import write_report
    from experiments.evaluation.sweep import read_rows
    from experiments.scenarios import resolve_scenarios

    config = TwinConfig(twins=args.twins, at=args.at, position_std=args.position_std, params=args.params,
                        param_scale=args.param_scale, threshold=args.threshold,
                        engine=getattr(args, "engine", "bullet"))
    if args.seeds < 1 or args.workers < 1:
        raise ValueError(f"--seeds and --workers must be >= 1, got {args.seeds}, {args.workers}")
    trials = []
    if args.evaluation is not None:
        path = os.path.join(args.evaluation, "trials.jsonl")
        if not os.path.exists(path):
            raise ValueError(f"--evaluation: no trials.jsonl in {args.evaluation}")
        trials = read_rows(path)
    names = resolve_scenarios([s.strip() for s in args.scenarios.split(",") if s.strip()])
    total = len(names) * args.seeds
    count = [0]

    def progress(row):
        count[0] += 1
        if not args.quiet:
            print(f"\r{count[0]} runs of twins done", end="", file=sys.stderr, flush=True)

    rows = run_twins(names, range(args.seeds), config, args.out, args.workers, progress)
    if not args.quiet and count[0]:
        print(file=sys.stderr)
    text = write_report(args.out, rows, trials, config)
    if not args.quiet:
        print(text)
        print(f"{total} (scenario, seed) pairs; written to {args.out}/", file=sys.stderr)
    return 0
