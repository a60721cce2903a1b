"""``scene-estimator search``: where to look first for an object, from the particle belief.

::

    scene-estimator search --scene s.yaml --observations o.jsonl --object cup [--at 12.5]
        [--viewpoints views.yaml] [--particles 64] [--json]

Runs the estimator over the stream up to ``--at`` (default: its end), then prints the search regions
ranked by probability, the order of the looks, the viewpoint of each, its probability of finding the
object and the expected cost (:func:`estimator.applications.search.plan_search`). ``--json`` prints one JSON
object (``regions``, ``plan``, ``expected_cost``, and ``object``, ``t``, ``p_found``, ``method``).
"""
from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from estimator.applications.search import SearchConfig, plan_search, read_viewpoints
from estimator.filter import SceneEstimator
from estimator.observations import ObservationReader
from physics.errors import InputError
from physics.scene import load_scene


def add_search_arguments(parser: argparse.ArgumentParser) -> None:
    from experiments.cli.common import add_estimator_arguments

    d = SearchConfig()
    parser.add_argument("--scene", required=True, help="scene file (YAML or JSON)")
    parser.add_argument("--observations", required=True, help="observation stream (JSON Lines)")
    parser.add_argument("--object", required=True, help="id of the object to find")
    parser.add_argument("--at", type=float, default=None,
                        help="stream time (s) to plan at: the frames up to it are read (default: the end)")
    parser.add_argument("--viewpoints", metavar="FILE",
                        help="viewpoint file (YAML): candidate cameras, costs, start, extra regions "
                             "(default: viewpoints sampled around the likely regions)")
    parser.add_argument("--fixed-cost", type=float, default=d.fixed_cost, help=f"cost of a look ({d.fixed_cost})")
    parser.add_argument("--travel-cost", type=float, default=d.travel_cost,
                        help=f"cost per metre of camera travel ({d.travel_cost})")
    parser.add_argument("--views-per-region", type=int, default=d.views_per_region,
                        help=f"viewpoints sampled around each likely region without --viewpoints ({d.views_per_region})")
    parser.add_argument("--json", action="store_true", help="print one JSON object and nothing else")
    add_estimator_arguments(parser)


def run_search(args: argparse.Namespace) -> int:
    """Run the ``search`` subcommand; bad input raises :class:`ValueError` (reported by ``main``)."""
    from experiments.cli.common import build_config

    if args.particles is None and not args.config:
        args.particles = 64
    cfg = build_config(args)
    search_cfg = SearchConfig(fixed_cost=args.fixed_cost, travel_cost=args.travel_cost,
                              views_per_region=args.views_per_region)
    scene = load_scene(args.scene)
    if args.object not in scene.object_ids:
        raise InputError(f"unknown object {args.object!r} (the scene {args.scene} has: "
                         f"{', '.join(scene.object_ids)})", field="--object")
    views = read_viewpoints(args.viewpoints) if args.viewpoints else None
    if args.at is not None and not math.isfinite(args.at):
        raise InputError(f"must be a finite time in seconds, got {args.at}", field="--at")
    frames = list(ObservationReader(args.observations, scene.object_ids))
    if not frames:
        raise InputError("the stream has no frames", path=args.observations)
    if args.at is not None and not frames[0].t <= args.at <= frames[-1].t:
        raise InputError(f"{args.at} s is outside the stream {args.observations} "
                         f"({frames[0].t:g} s to {frames[-1].t:g} s)", field="--at")
    hands: dict = {}
    with SceneEstimator(scene, cfg, np.random.default_rng(args.seed)) as est:
        for f in frames:
            if args.at is not None and f.t > args.at:
                break
            est.update(f)
            hands = dict(f.hands) if f.hands else hands
        t0 = time.perf_counter()
        try:
            plan = plan_search(est, args.object, views, search_cfg, np.random.default_rng(args.seed), hands)
        except ValueError as exc:
            raise InputError(str(exc), field="--object") from None
        planning_ms = 1e3 * (time.perf_counter() - t0)
        particles = est.K  # (with an adaptive count, the K of the last update)
    if args.json:
        print(json.dumps({**plan.to_json(), "planning_ms": round(planning_ms, 1)}))
        return 0
    print_plan(plan, particles)
    print(f"\nPlanned in {planning_ms:.0f} ms ({plan.candidates} candidate viewpoints).")
    return 0


def print_plan(plan, particles: int) -> None:
    """The plan, readable."""
    when = f"t = {plan.t:.3f} s" if plan.t is not None else "the start"
    print(f"Where is {plan.object_id}? (at {when}, {particles} particles)")
    width = max(len(n) for n, _ in plan.regions)
    for name, p in plan.regions:
        print(f"  {name + ':':<{width + 1}} {p:.2f}")
    print(f"\nLook order ({plan.method}; expected cost {plan.expected_cost:.2f}, "
          f"found by the plan with p = {plan.p_found:.2f}):")
    if not plan.looks:
        print("  (no viewpoint sees any likely place)")
    for i, lk in enumerate(plan.looks, start=1):
        c = lk.viewpoint.camera
        pos = ", ".join(f"{v:.2f}" for v in c.position)
        tgt = ", ".join(f"{v:.2f}" for v in c.target)
        print(f"  {i}. {', '.join(lk.regions)}: viewpoint {lk.viewpoint.id} at ({pos}) looking at ({tgt}); "
              f"p(find) = {lk.p_find:.2f} (first find {lk.p_first:.2f}), cost {lk.cost:.2f}")
