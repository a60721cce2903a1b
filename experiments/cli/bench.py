"""``scene-estimator bench``: update time of the estimator against bare pybullet stepping.

Two kinds of input, timed by the same loop (:func:`experiments.bench.timing.time_stream`):

* synthetic (``--objects``, :mod:`experiments.bench.synthetic`): for each particle count K and number
  of dynamic objects N (5 cm boxes resting on a table, perceived floating 1 cm with 3 mm noise), one
  frame per reasoning horizon (0.08 s, 19 steps), 3 untimed warm-up updates, then ``--updates``
  timed ones;
* scenarios (``--scenario``, :mod:`experiments.bench.scenarios`): the observation stream of a
  built-in simulated scenario (seed 0), every frame of it, so that the real-time factor can be read
  off.

``--breakdown`` adds where the update's time goes; ``--bag`` compares JSONL and ROS-bag input;
``--rerun-overhead`` the cost of recording; ``--live`` (with ``--scenario``) feeds each stream at its
real rate through a pipe into the live loop and reports the latency from a frame's arrival to the
estimate that used it and the frames merged (:mod:`experiments.bench.live`).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Iterable

from estimator.config import EstimatorConfig, config_from_dict, read_config_file
from experiments.bench.repeat import P95_HORIZONS, rounds, summarise, summary_table
from experiments.bench.synthetic import bench_one
from experiments.bench.timing import (
    BREAKDOWN_COLUMNS,
    RESOURCE_COLUMNS,
    SYNTHETIC_COLUMNS,
    TIMING_COLUMNS,
    bench_config,
)
from experiments.cli.common import AUTO_RANGE, add_fixed_particles_argument, live_config, particle_count


def report(args, columns: list[tuple[str, str, str]], rows: Iterable[dict], meta: dict,
           horizon_s: float | None = None) -> int:
    """Print ``rows`` as they come as a Markdown table (``--breakdown``: with its columns), or, with
    ``--json``, all of them at the end as one JSON object ``{**meta, "results": rows}``. With
    ``--repeat`` N > 1 each row shows its run, and a second table (JSON: ``"summary"``) follows with
    each configuration's figures over its runs and how many kept up with the reasoning horizon
    ``horizon_s`` (s; :func:`~experiments.bench.repeat.summarise`; None only for the tables never
    repeated: ``--bag``)."""
    if args.breakdown:
        columns = columns + BREAKDOWN_COLUMNS
    if args.repeat > 1:
        columns = columns[:2] + [("run", "run", "{}")] + columns[2:]
    if not args.json:
        print("| " + " | ".join(c[1] for c in columns) + " |")
        print("|" + "---|" * len(columns), flush=True)
    done = []
    for r in rows:
        done.append(r)
        if not args.json:
            print("| " + " | ".join(fmt.format(r[key]) for key, _, fmt in columns) + " |", flush=True)
    summary = summarise(done, args.repeat, horizon_s) if args.repeat > 1 else None
    if args.json:
        print(json.dumps({**meta, "results": done, **({"summary": summary} if summary is not None else {})}))
    elif summary is not None:
        print(f"\nOver {args.repeat} runs (kept up: real-time factor above 1 where measured, median update under the "
              f"{1e3 * horizon_s:.0f} ms horizon, p95 under {P95_HORIZONS * 1e3 * horizon_s:.0f} ms):\n")
        print("\n".join(summary_table(summary)), flush=True)
    return 0


def particle_configs(args) -> list[tuple[int, EstimatorConfig]]:
    """``(K, configuration)`` for each ``--particles``: the ``--config`` file's or the particle filter's
    defaults, with K particles and ``--workers`` workers; with ``--live``, as ``run --live`` takes it
    (:func:`~experiments.cli.common.live_config`)."""
    file_data = read_config_file(args.config) if args.config else None
    out = []
    for k in args.particles:
        cfg = None
        if file_data is not None:
            cfg = config_from_dict(file_data[0], path=args.config, lines=file_data[1],
                                   particles=None if k == "auto" else k, base="particles")
        out.append((k, live_config(bench_config(k, args.workers, cfg), args.live, args.fixed_particles)))
    return out


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--particles", type=particle_count, nargs="+", default=[16, 64, 256],
                   help="particle counts to time (default 16 64 256); auto: the adaptive count (KLD-sampling "
                        f"{AUTO_RANGE}, from the fewest; the table's K column then shows the mean K of the "
                        "timed updates)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--objects", type=int, nargs="+", default=None,
                      help="synthetic scenes: resting boxes on a table (default 4 8 12)")
    what.add_argument("--scenario", metavar="NAME", action="append", default=None,
                      help="replay a built-in simulated scenario's observation stream (seed 0) instead; "
                           "repeat for several, 'all' for every built-in one (see `simulate --list`)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="worker processes (default: one per core)")
    p.add_argument("--updates", type=int, default=None,
                   help="timed updates per configuration (default 20; with --scenario, default: the whole "
                        "stream; given: the stream stops after this many)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument("--bag", action="store_true",
                   help="with --scenario: time a run of the stream read from JSON Lines against one read from "
                        "a ROS 2 bag of the same detections from two sources (/tf and PoseStamped)")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="estimator configuration file (see `scene-estimator config`) to time instead of the "
                        "particle filter's defaults, e.g. 'noise: {rolling_friction_range: [0.001, 0.01]}'")
    p.add_argument("--breakdown", action="store_true",
                   help="also print where an update's time goes: the main process's own work, the slowest "
                        "shard in its worker, the exchange (waiting for it, messages, shared arrays), and "
                        "each worker's time over bare stepping per particle, and the share of bare stepping that "
                        "objects at rest cost (the worlds stepped again with them out of collision)")
    p.add_argument("--rerun-overhead", action="store_true",
                   help="measure the cost of --rerun recording instead (e.g. --particles 64)")
    p.add_argument("--live", action="store_true",
                   help="with --scenario: feed each stream at its real rate through a pipe into the live loop "
                        "(run --live) and report the latency from a frame's arrival to the estimate that used it "
                        "(median, p95, max), the frames merged and the particle count (shed while a step cannot "
                        "keep up, as in run --live; --fixed-particles: not)")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="measure every configuration N times, round by round (every configuration once, then "
                        "again), each row with its run; then a table of each configuration's median and range "
                        "over the runs and how many kept up (real-time factor above 1, median update under the "
                        "reasoning horizon, p95 under 1.5 horizons: 80 and 120 ms by default)")
    add_fixed_particles_argument(p)


def run_bench(args) -> int:
    if args.updates is not None and args.updates < 1:
        raise ValueError(f"--updates must be >= 1, got {args.updates}")
    if args.repeat < 1:
        raise ValueError(f"--repeat must be >= 1, got {args.repeat}")
    if args.repeat > 1 and (args.bag or args.rerun_overhead):
        raise ValueError("--repeat goes with the timing tables: drop --bag and --rerun-overhead")
    if args.bag and not args.scenario:
        raise ValueError("--bag compares the streams of scenarios: give --scenario NAME")
    if args.bag and args.breakdown:
        raise ValueError("--breakdown splits an update's time; --bag times whole runs: give one of them")
    if args.live and not args.scenario:
        raise ValueError("--live feeds the streams of scenarios: give --scenario NAME (or all)")
    if args.live and (args.bag or args.breakdown or args.updates is not None):
        raise ValueError("--live times whole streams at their real rate: drop --bag, --breakdown and --updates")
    if args.scenario:
        if args.rerun_overhead:
            raise ValueError("--rerun-overhead times the synthetic scenes (--objects), not --scenario")
        return _scenario_bench(args)
    objects = args.objects or [4, 8, 12]
    updates = args.updates or 20
    if args.rerun_overhead:
        from experiments.bench.recording import logging_overhead
        rows = [logging_overhead(k, n, args.workers, updates) for k in args.particles for n in objects]
        if args.json:
            print(json.dumps({"workers": args.workers, "results": rows}))
        else:
            for r in rows:
                print(f"K={r['particles']:>4} N={r['objects']:>3} update {r['update_ms_median']:.1f} ms  "
                      f"log {r['log_ms_median']:.2f} ms  overhead {100 * r['overhead']:.1f} %")
        return 0
    configs = particle_configs(args)

    def measure(item: tuple[int | str, EstimatorConfig, int]) -> dict:
        k, cfg, n = item
        print(f"bench: K={k}, {n} objects", file=sys.stderr, flush=True)
        return bench_one(k, n, args.workers, updates, config=cfg, resting=args.breakdown)

    columns = (SYNTHETIC_COLUMNS + TIMING_COLUMNS + [("updates_per_s", "updates/s", "{:.1f}")]
               + RESOURCE_COLUMNS)
    meta = {"mode": "synthetic", "workers": args.workers, "cpu_count": os.cpu_count(), "config": args.config}
    rows = rounds([(k, cfg, n) for k, cfg in configs for n in objects], measure, args.repeat)
    return report(args, columns, rows, meta, configs[0][1].reasoner.horizon)


def _scenario_bench(args) -> int:
    from experiments.bench.scenarios import SCENARIO_COLUMNS, SEED, bag_table, scenario_rows
    from experiments.scenarios import resolve_scenarios

    names = resolve_scenarios(args.scenario)
    configs = particle_configs(args)
    horizon = configs[0][1].reasoner.horizon  # one reasoner for every K (the --config file's or the defaults)
    meta = {"mode": "bag" if args.bag else "scenario", "seed": SEED, "workers": args.workers,
            "cpu_count": os.cpu_count(), "config": args.config}
    if args.bag:
        from experiments.bench.bag import BAG_COLUMNS
        return report(args, BAG_COLUMNS, bag_table(names, configs), meta)
    if args.live:
        from experiments.bench.live import LIVE_COLUMNS, live_rows
        meta.update(mode="live", load_average_at_start=list(os.getloadavg()),
                    fixed_particles=bool(args.fixed_particles))
        return report(args, LIVE_COLUMNS, live_rows(names, configs, repeat=args.repeat), meta, horizon)
    return report(args, SCENARIO_COLUMNS, scenario_rows(names, configs, args.updates, args.breakdown, args.repeat),
                  meta, horizon)
