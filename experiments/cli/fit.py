"""``scene-estimator fit-priors``: the held-object priors fitted on simulated scenarios
(:func:`experiments.evaluation.fit_priors.fit_priors`), printed as JSON."""
from __future__ import annotations

import argparse
import json

from experiments.evaluation.fit_priors import FIT_SEEDS, fit_priors


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
                   help="'all' (every built-in scenario with tracked hands) or comma-separated names")


def run_fit(args) -> int:
    names = None if args.scenarios == "all" else [s.strip() for s in args.scenarios.split(",") if s.strip()]
    print(json.dumps(fit_priors(names, seed_range(args.seeds)), indent=1))
    return 0
