"""``scene-estimator search-eval``: the hidden-object search experiment
(:mod:`experiments.search.experiment`)."""
from __future__ import annotations

import argparse
import os

from experiments.search.experiment import SEARCH_SCENARIOS, SearchSweepConfig, run_search_sweep


def add_search_eval_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``search-eval``."""
    p.add_argument("--scenarios", default="all",
                   help="'all' (the built-in scenarios that end with a hidden object: "
                        f"{', '.join(SEARCH_SCENARIOS)}) or comma-separated names or scenario files")
    p.add_argument("--seeds", type=int, default=20, help="seeds 0..N-1 per scenario (default 20)")
    p.add_argument("--particles", type=int, default=64, help="particles of the particle estimator (default 64)")
    p.add_argument("--duration", type=float, default=None, help="override the scenarios' durations (s)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="trials in parallel (default: one per core); rows do not depend on it")
    p.add_argument("--out", required=True, help="output folder (search_trials.jsonl, search_summary.md, ...)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run_search_eval(args) -> int:
    from experiments.scenarios import resolve_scenarios

    names = list(SEARCH_SCENARIOS) if args.scenarios == "all" else resolve_scenarios(
        [s.strip() for s in args.scenarios.split(",") if s.strip()])
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be > 0 s, got {args.duration}")
    cfg = SearchSweepConfig(tuple(names), tuple(range(args.seeds)), args.particles, args.duration)
    rows = run_search_sweep(cfg, args.out, workers=args.workers, progress=not args.no_progress)
    hidden = sum(1 for r in rows if r.get("target"))
    print(f"{len(rows)} trials, {hidden} with a hidden object; summary in {os.path.join(args.out, 'search_summary.md')}")
    return 0
